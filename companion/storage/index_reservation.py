"""The next image index, persisted before an index is announced, so no later run hands the same index out again.

summary.json also records the next index, but it is rewritten whole (a new file, then a rename), which a full
disk refuses: a run that went memory-only then announced indices its summary file never heard of, and the next run
announced them again under the same dive id (the surface showed the wrong thumbnails). This file is a fixed
32-byte record overwritten in place (``pwrite`` + ``fsync``): an overwrite needs no new blocks, so it still works
on a full disk. Only a read-only or failing disk refuses it; the store then gives the run a new dive id.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from vehicle.camera.capture_frame import MAX_IMAGE_INDEX

log = logging.getLogger(__name__)

RECORD_BYTES = 32
MAX_INDEX = MAX_IMAGE_INDEX
"""The highest image index there can be: CAMERA_IMAGE_CAPTURED carries it as an int32. The next index may be one
more (``USED_UP``: every index was handed out); a claim beyond that (a damaged file, a hand edit) was never
handed out, so a store drops it instead of trusting it."""
USED_UP = MAX_INDEX + 1


def valid_index(value: object) -> bool:
    """A whole number an image index can be; not a bool, a float or a string."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_INDEX


def valid_next(value: object) -> bool:
    """A whole number the next image index can be: an image index, or ``USED_UP``."""
    return valid_index(value) or (value == USED_UP and not isinstance(value, (bool, float)))


class IndexReservation:
    """``load()`` the highest next-index ever reserved (0: none); ``save(n)`` persists n (OSError when refused)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.saved = 0

    def load(self) -> int:
        try:
            text = self.path.read_bytes()[:RECORD_BYTES].decode("ascii").strip()
            self.saved = int(text or 0)
        except (OSError, ValueError, UnicodeDecodeError):
            self.saved = 0  # absent or damaged: summary.json and the frames on disk still give a floor
        if not valid_next(self.saved):
            log.warning("%s: next image index %s is not one MAVLink can announce (0-%d, or %d once all are used); "
                        "ignored", self.path, self.saved, MAX_INDEX, USED_UP)
            self.saved = 0
        return self.saved

    def save(self, value: int, *, force: bool = False) -> None:
        """Overwrite the record in place and fsync it; ``force``: also when the value is not higher (at start: the
        file then exists, made while the disk still has room, and a disk that refuses it is known at once)."""
        if value <= self.saved and not force:
            return
        record = f"{value:>{RECORD_BYTES - 1}d}\n".encode("ascii")
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            if os.pwrite(fd, record, 0) != RECORD_BYTES:
                raise OSError(f"short write to {self.path}")
            os.fsync(fd)
        finally:
            os.close(fd)
        self.saved = max(self.saved, value)
