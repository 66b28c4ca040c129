"""Where a capture's thumbnail lies in DIR: moved along when the frame changes place (summary, removed, an earlier
dive), deleted when the frame is forgotten (and the dive folders that leaves empty)."""

from __future__ import annotations

import os
from pathlib import Path

from companion.topside.capture import Capture


def inside(root: Path, rel: str) -> Path | None:
    """``root / rel`` when it stays inside ``root`` (links followed), else None: a thumbnail path read back from
    gallery.json (a file anyone with the folder can edit) never moves or deletes a file elsewhere."""
    path = Path(rel)
    if not rel or path.is_absolute() or ".." in path.parts:
        return None
    full = root / path
    try:
        real_root = root.resolve()
        if real_root not in full.resolve().parents:
            return None
    except (OSError, RuntimeError):
        return None
    return full


def move_thumbnail(root: Path, cap: Capture, folder: str) -> None:
    """Keep ``cap``'s thumbnail in ``folder`` (relative to ``root``), the folder that matches its state."""
    if cap.thumbnail:
        src = inside(root, cap.thumbnail)
        if src is None:  # not ours to move: the capture keeps no thumbnail
            cap.thumbnail = None
            return
        rel = f"{folder}/{Path(cap.thumbnail).name}"
        if src.exists():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, root / rel)
        cap.thumbnail = rel


def forget_thumbnail(root: Path, cap: Capture) -> None:
    """Delete ``cap``'s thumbnail, and the folders under ``dives/`` that leaves empty."""
    if not cap.thumbnail:
        return
    path = inside(root, cap.thumbnail)
    if path is None:  # outside DIR: never deleted
        return
    path.unlink(missing_ok=True)
    dives, folder = root / "dives", path.parent
    while dives in folder.parents:
        try:
            folder.rmdir()
        except OSError:
            break  # not empty
        folder = folder.parent
