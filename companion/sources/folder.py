"""A folder of still images in natural order (frame2 before frame10), one frame per image.

Stills carry no clock, so image i gets ``time_s = i / fps``: the folder plays as a camera at the target rate
and nothing is subsampled away; ``origin(index)`` names the file a frame came from, which a summary keeps. Unreadable images are skipped and counted in ``lost``.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2

from companion.errors import UsageError
from companion.sources.base import FrameSource
from companion.sources.frame import Frame
from companion.sources.subsample import Pacer

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm"})


def natural_key(name: str) -> list:
    """Sort key that compares runs of digits as numbers: img2.jpg < img10.jpg."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in re.split(r"(\d+)", name) if part]


def list_images(folder: Path) -> list[Path]:
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=lambda p: natural_key(p.name))


def image_subfolders(folder: Path, depth: int = 2) -> list[tuple[str, int]]:
    """Subfolders (down to ``depth`` levels, relative names) that hold images, with how many, in natural order."""
    found: list[tuple[str, int]] = []
    try:
        subs = sorted((p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")),
                      key=lambda p: natural_key(p.name))
    except OSError:
        return found
    for sub in subs:
        try:
            count = sum(1 for p in sub.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        except OSError:
            continue
        if count:
            found.append((sub.name, count))
        if depth > 1:
            found.extend((f"{sub.name}/{name}", n) for name, n in image_subfolders(sub, depth - 1))
    return found


def no_images_error(folder: Path) -> UsageError:
    """A folder without images is bad input (exit 2); where images sit one or two levels down, say where."""
    line = f"{folder}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in this folder"
    subs = image_subfolders(folder)
    if subs:
        shown = ", ".join(f"{name}/ ({n})" for name, n in subs[:3]) + (f" and {len(subs) - 3} more"
                                                                      if len(subs) > 3 else "")
        line += f"; images are in its subfolder{'s' * (len(subs) > 1)} {shown}: name one"
    return UsageError(line)


def collect_images(paths: Sequence[str | Path]) -> list[Path]:
    """Files as given and the images inside folders (natural order); a missing path is a usage error."""
    out: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = list_images(path)
            if not found:
                raise no_images_error(path)
            out.extend(found)
        elif path.is_file():
            out.append(path)
        else:
            raise UsageError(f"{path}: no such file or folder")
    return out


class FolderSource(FrameSource):
    def __init__(self, folder: str | Path, *, fps: float = 5.0, realtime: bool = False, loop: bool = False) -> None:
        self.folder = Path(folder)
        self.name = str(self.folder)
        self.fps = float(fps)
        self.realtime = realtime
        self.loop = loop
        self.lost = 0
        if not self.folder.is_dir():
            raise UsageError(f"{self.folder}: no such folder")
        self.files = list_images(self.folder)
        if not self.files:
            raise no_images_error(self.folder)

    def origin(self, index: int) -> str | None:
        """The name of the image that frame ``index`` was read from (indices count every file, readable or not,
        and keep counting round a loop)."""
        return self.files[index % len(self.files)].name if index >= 0 else None

    def __iter__(self) -> Iterator[Frame]:
        pacer = Pacer(self.realtime)
        index, decoded = 0, 0
        while True:
            for path in self.files:
                image = cv2.imread(str(path), cv2.IMREAD_COLOR)
                if image is None:
                    self.lost += 1
                    log.warning("%s: not a readable image, skipped", path)
                else:
                    decoded += 1
                    time_s = index / self.fps
                    pacer.wait(time_s)
                    yield Frame(image, index, time_s, time.time())
                index += 1
            if decoded == 0:
                raise UsageError(f"{self.folder}: none of its {len(self.files)} images could be read")
            if not self.loop:
                return
