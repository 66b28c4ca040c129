"""Where a capture's thumbnail lies in DIR: moved along when the frame changes place (summary, removed, an earlier
dive), deleted when the frame is forgotten (and the dive folders that leaves empty)."""

from __future__ import annotations

import os
from pathlib import Path

from companion.topside.capture import Capture


def move_thumbnail(root: Path, cap: Capture, folder: str) -> None:
    """Keep ``cap``'s thumbnail in ``folder`` (relative to ``root``), the folder that matches its state."""
    if cap.thumbnail:
        src = root / cap.thumbnail
        rel = f"{folder}/{Path(cap.thumbnail).name}"
        if src.exists():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, root / rel)
        cap.thumbnail = rel


def forget_thumbnail(root: Path, cap: Capture) -> None:
    """Delete ``cap``'s thumbnail, and the folders under ``dives/`` that leaves empty."""
    if not cap.thumbnail:
        return
    path = root / cap.thumbnail
    path.unlink(missing_ok=True)
    dives, folder = root / "dives", path.parent
    while dives in folder.parents:
        try:
            folder.rmdir()
        except OSError:
            break  # not empty
        folder = folder.parent
