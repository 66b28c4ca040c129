"""Where an export points at its images: relative to the export file, so the folder can be moved as a whole."""

from __future__ import annotations

import os
from pathlib import Path


def relative_url(image: Path, out: Path) -> str:
    """``image`` relative to the folder of ``out``, with forward slashes (what COCO, DIVE and URLs expect)."""
    return Path(os.path.relpath(image.resolve(), out.resolve().parent)).as_posix()
