"""Whether the store is writing to disk, and who hears when that changes.

A full or read-only disk makes the store keep the summary in memory; it says so once (to the log and to its
listeners: the companion turns that into a STATUSTEXT at WARNING for the surface), retries every ``retry_s``, and
says so again when it is back on disk.
"""

from __future__ import annotations

import errno
import logging
import time
from collections.abc import Callable

from companion.storage.store_lock import StoreReplaced

log = logging.getLogger("companion.storage.store")

RETRY_S = 5.0
"""How often a memory-only store tries the disk again (a probe write: cheap)."""

Listener = Callable[[bool, str], None]
"""Called with (memory_only, reason) when the store leaves the disk or comes back to it."""

_REASONS = {errno.ENOSPC: "disk full", errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
            errno.EDQUOT: "disk quota exceeded"}


def reason_of(err: OSError) -> str:
    return _REASONS.get(err.errno, err.strerror or str(err))


class StoreHealth:
    """Memory-only or on disk, why, and when to try the disk again."""

    def __init__(self, directory: object, *, retry_s: float = RETRY_S, clock: Callable[[], float] = time.monotonic):
        self.directory = directory
        self.retry_s = retry_s
        self.clock = clock
        self.memory_only = False
        self.reason = ""
        self.write_errors = 0
        self.recoveries = 0
        self.lost = False
        """The store's folder was replaced under the run (``StoreReplaced``): memory-only for good, no retries."""
        self._tried_at = clock()
        self._listeners: list[Listener] = []

    def on_change(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def degrade(self, err: OSError) -> None:
        """A write failed: memory-only from now on; said once until the store is back on disk."""
        self.write_errors += 1
        if isinstance(err, StoreReplaced):
            self._lose(err)
            return
        if self.memory_only:
            return
        self.memory_only = True
        self.reason = reason_of(err)
        self._tried_at = self.clock()
        log.warning("store %s: %s; keeping the summary in memory only (frames saved before are intact)",
                    self.directory, self.reason)
        self._tell()

    def _lose(self, err: StoreReplaced) -> None:
        """Said once, as an error: the path is another store's now (or none), so no retry ever writes there."""
        if self.lost:
            return
        self.lost = self.memory_only = True
        self.reason = "folder replaced"
        log.error("%s", err.strerror)
        self._tell()

    def retry_due(self) -> bool:
        """True (at most once per ``retry_s``) when a memory-only store should try the disk again."""
        if not self.memory_only or self.lost or self.clock() - self._tried_at < self.retry_s:
            return False
        self._tried_at = self.clock()
        return True

    def recovered(self, written: int) -> None:
        self.memory_only = False
        self.recoveries += 1
        log.warning("store %s: writable again (was %s); %d frames kept in memory written to disk", self.directory,
                    self.reason, written)
        self.reason = ""
        self._tell()

    def _tell(self) -> None:
        for listener in self._listeners:
            try:
                listener(self.memory_only, self.reason)
            except Exception:  # noqa: BLE001 - a listener (the surface link) must never stop the store
                log.exception("store %s: health listener failed", self.directory)
