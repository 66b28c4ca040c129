"""Where an export points at its images: relative to the export file, so the folder can be moved as a whole."""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import quote


def relative_url(image: Path, out: Path) -> str:
    """``image`` relative to the folder of ``out``, with forward slashes (what COCO, DIVE and URLs expect); links
    are not followed (``FrameEntry.image`` refuses them in a store), only ``..`` and ``.`` are resolved."""
    return Path(os.path.relpath(os.path.abspath(image), os.path.abspath(out.parent))).as_posix()


def image_root(images: list[Path]) -> Path:
    """The deepest folder holding every image (a store's frames/, a campaign's folder): what a server serves."""
    if not images:
        return Path(".")
    return Path(os.path.commonpath([os.path.abspath(p.parent) for p in images]))


def absolute_url(image: Path, root: Path, base_url: str | None) -> str:
    """Where FathomNet finds the image: ``base_url`` + its path under ``root`` (``image_root``: serve that folder
    at ``base_url``), or with no base URL the image's own absolute ``file://`` URL."""
    if base_url:
        rel = Path(os.path.relpath(os.path.abspath(image), root)).as_posix()
        return f"{base_url.rstrip('/')}/{quote(rel)}"
    return Path(os.path.abspath(image)).as_uri()
