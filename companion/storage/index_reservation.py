"""The next image index, persisted before an index is announced, so no later run hands the same index out again.

summary.json also records the next index, but it is rewritten whole (a new file, then a rename), which a full
disk refuses: a run that went memory-only then announced indices its summary file never heard of, and the next run
announced them again under the same dive id (the surface showed the wrong thumbnails). This file is a fixed
32-byte record overwritten in place (``pwrite`` + ``fsync``): an overwrite needs no new blocks, so it still works
on a full disk. Only a read-only or failing disk refuses it; the store then gives the run a new dive id
(``DiveIndex``), at start or at any time later: a (dive, index) pair the surface heard is never announced again.
"""

from __future__ import annotations

import logging
import os
import secrets
from pathlib import Path

from vehicle.camera.capture_frame import MAX_IMAGE_INDEX

log = logging.getLogger("companion.storage.store")

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


class DiveIndex:
    """The dive id the store announces under, and the reservation that makes announcing safe.

    An index may be announced under a dive only once the next index is persisted for that dive (``reserve``). When
    it cannot be (a read-only remount, a failing disk, the index file's own write failing: any ``OSError``, at any
    time), the dive id is given up at once for a new one that was never on disk, before the index is announced:
    the next run, resuming the old dive from the last persisted index, can then never announce a pair this run
    announced. Said once per failure (the log here; ``changes`` tells the app, which tells the surface); the new
    id reaches the disk only after its own next index does (``recovered``).
    """

    def __init__(self, path: Path, directory: object) -> None:
        self.reservation = IndexReservation(path)
        self.directory = directory
        self.dive = ""
        self.refused = False
        """The last write of the next index failed: the dive in use was made for this failure (not yet on disk)."""
        self.changes = 0
        """Dive ids given up since the start because their next index could not be persisted."""

    def start(self, saved_dive: str, next_index: int) -> OSError | None:
        """At start: the saved dive goes on if ``next_index`` can be persisted, else (a dive the last run may have
        announced past what it saved) a new one; a store without a dive gets one. The error, if any."""
        self.dive = saved_dive or secrets.token_hex(4)
        try:
            self.reservation.save(next_index, force=True)
        except OSError as err:
            self.refused = True  # said here: not again at the first frame
            if saved_dive:
                self.dive = secrets.token_hex(4)
                log.warning("store %s: image indices cannot be persisted (%s); this run's dive id is %s",
                            self.directory, err.strerror or err, self.dive)
            return err
        return None

    def without_disk(self) -> None:
        """No store folder could be made: a dive id of its own, and nothing is written (not even over a record
        that may be there)."""
        self.dive = secrets.token_hex(4)
        self.refused = True

    def reserve(self, next_index: int) -> OSError | None:
        """Before index ``next_index - 1`` is announced: persist ``next_index``; on failure (the first of a spell)
        the dive id changes. The error, if any."""
        try:
            self.reservation.save(next_index)
        except OSError as err:
            if not self.refused:
                self.give_up(next_index - 1, err.strerror or str(err))
            return err
        self.refused = False
        return None

    def give_up(self, first: int, reason: str) -> None:
        """Index ``first`` and those after it cannot be reserved under the dive in use: a new dive id from now on."""
        self.refused = True
        old, self.dive = self.dive, secrets.token_hex(4)
        self.changes += 1
        log.warning("store %s: image indices from %d on cannot be persisted (%s); announcing under a new dive id %s "
                    "(was %s), so no (dive, index) pair is announced twice", self.directory, first, reason,
                    self.dive, old)

    def recovered(self, next_index: int) -> None:
        """The disk takes writes again: persist the next index for the dive in use (OSError when it still cannot)."""
        self.reservation.save(next_index, force=True)
        self.refused = False
