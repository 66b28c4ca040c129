"""What a campaign is made of: one dive per video file or image folder, named, sized and placed in time.

A SOURCE on the command line is a video, a folder of images (one dive), or a folder of videos (one dive each,
searched recursively). A dive's start time comes from the file: a recorder closes a video when it stops, so the
start is the file's modification time less the video's duration (``mapping`` files in ``log_match`` override it
when the copy lost the times). Names are the file stems, made unique with a short path hash when two collide.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2

from companion.errors import MerlionError, UsageError
from companion.sources.folder import IMAGE_SUFFIXES

VIDEO_SUFFIXES = frozenset({".mp4", ".mov", ".mkv", ".avi", ".m4v", ".ts", ".mts", ".h264", ".h265", ".hevc",
                            ".mjpeg", ".webm"})

RESERVED_NAMES = frozenset({"report", "manifest.json", "index.html", "index.csv", "index.json"})
"""Names the campaign folder uses itself: a dive called so gets the path hash too."""


@dataclass(frozen=True)
class Dive:
    """One unit of work: a video or image folder and what the campaign knows about it before summarizing."""

    name: str
    source: Path
    duration_s: float
    """Seconds of footage (0 when the container does not say)."""
    frame_count: int
    source_fps: float
    start_time: float
    """Wall-clock time of the first frame, seconds since the epoch (from the file times)."""

    @property
    def end_time(self) -> float:
        return self.start_time + self.duration_s


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def find_sources(paths: Iterable[str | Path]) -> list[Path]:
    """Every video and image folder named by ``paths``, in a stable order; MerlionError for a bad path."""
    found: list[Path] = []
    for raw in paths:
        p = Path(raw).expanduser().resolve()
        if p.is_file():
            if p.suffix.lower() not in VIDEO_SUFFIXES:
                raise MerlionError(f"{raw}: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}) or a folder")
            found.append(p)
        elif p.is_dir():
            videos = sorted(v for v in p.rglob("*") if v.is_file() and v.suffix.lower() in VIDEO_SUFFIXES)
            if videos:
                found.extend(videos)
            elif _images(p):
                found.append(p)
            else:
                raise MerlionError(f"{raw}: no videos and no images in this folder")
        else:
            raise UsageError(f"{raw}: no such file or folder")
    unique = list(dict.fromkeys(found))
    if not unique:
        raise MerlionError("no sources given")
    return unique


def _measure(source: Path) -> tuple[float, int, float, float]:
    """(duration, frame count, fps, start time) of a video or image folder."""
    if source.is_dir():
        images = _images(source)
        return 0.0, len(images), 0.0, min(p.stat().st_mtime for p in images)
    cap = cv2.VideoCapture(str(source))
    try:
        if not cap.isOpened():
            return 0.0, 0, 0.0, source.stat().st_mtime
        count = max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT)))
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    finally:
        cap.release()
    duration = count / fps if count and fps > 0 else 0.0
    return duration, count, fps, source.stat().st_mtime - duration


def make_dives(sources: list[Path]) -> list[Dive]:
    """A Dive per source, uniquely named (an unreadable video still becomes a dive: its task reports it)."""
    stems = [s.stem if s.is_file() else s.name for s in sources]
    dives = []
    for source, stem in zip(sources, stems, strict=True):
        name = stem
        if stems.count(stem) > 1 or name.lower() in RESERVED_NAMES:
            name = f"{stem}-{hashlib.sha1(str(source).encode()).hexdigest()[:8]}"
        duration, count, fps, start = _measure(source)
        dives.append(Dive(name, source, duration, count, fps, start))
    return dives
