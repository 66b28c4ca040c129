"""One writer per store directory, across processes: an exclusive ``flock`` on ``<store>/lock``.

Two `merlion run` (or a run and a demo) on one store each hand out the same image indices and overwrite each
other's frames and summary.json; the opening run also sweeps up the other's temporary files. The lock is taken
before the store is opened and held for the whole run. ``flock`` belongs to the open file, so the kernel drops it
when the holder exits, however it exits (SIGKILL, a power cut's reboot): there is no stale lock to clear by hand.
The holder writes its pid into the file, so the refusal names who holds it. A store whose folder cannot take the
lock file (read-only and never used) runs without the lock: such a store is memory-only and writes nothing.

The lock guards one folder, not the path: a folder renamed away (or deleted, or its lock file removed) while a run
holds it leaves the path free for a new folder and a second process to lock. So the holder checks, before it
writes (``check``), that the path still leads to the lock file it holds (same device and inode); when it does not,
the store stops writing there for good (``StoreReplaced``), instead of writing into the other process's store.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
from collections.abc import Iterator
from pathlib import Path

from companion.errors import UsageError

log = logging.getLogger(__name__)

LOCK_FILE = "lock"


class StoreInUse(UsageError):
    """Another live process holds the store (exit 2: nothing was started or written)."""


class StoreReplaced(OSError):
    """The store's path no longer leads to the folder this run locked: it writes nothing more there."""


class StoreLock:
    """``acquire()`` once before the store is opened; ``release()`` at the end (the OS releases it on any exit)."""

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.dir = Path(directory)
        self.path = self.dir / LOCK_FILE
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock or raise StoreInUse naming the store and the holder's pid."""
        fd = self._open()
        if fd is None:
            return
        try:
            _flock_or_refuse(fd, fcntl.LOCK_EX, self.dir)
        except BaseException:  # refused, or the lock call failed: the descriptor goes either way
            os.close(fd)
            raise
        self._fd = fd
        try:  # who holds it, for the next one refused (a full disk may refuse: the lock itself still holds)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        except OSError as err:
            log.debug("store %s: pid not written to %s (%s)", self.dir, self.path, err)

    def _open(self) -> int | None:
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            return os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            try:  # a read-only disk: a lock file left by an earlier run still takes the lock
                return os.open(self.path, os.O_RDONLY)
            except OSError:
                log.debug("store %s: no lock file (%s); a store that cannot make one writes nothing", self.dir,
                          err.strerror or err)
                return None

    def check(self) -> None:
        """Raise StoreReplaced unless ``<store>/lock`` is still the file this process holds (nothing to check
        without a lock: such a store writes nothing). A stat of the path and one of the descriptor: cheap enough
        before every change."""
        if self._fd is None:
            return
        held = os.fstat(self._fd)
        try:
            now = os.stat(self.path)
        except FileNotFoundError:
            why = "its lock file is gone: the folder was renamed or deleted, or the lock file removed"
        except OSError:
            return  # cannot tell (a failing disk): the store's own writes will say what is wrong
        else:
            if (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
                return
            why = "its lock file is another one: the folder or the lock file was replaced"
        raise StoreReplaced(errno.ESTALE, f"store {self.dir}: replaced under this run ({why}); this run writes "
                            f"nothing more there and keeps its summary in memory (what it saved is in the folder "
                            f"it locked; a restart takes the folder now at the path)")

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the only descriptor drops the flock
            self._fd = None


def check_free(directory: str | os.PathLike[str]) -> None:
    """Raise StoreInUse if a live process holds the store at ``directory``; creates nothing (the demo asks this
    before it moves an earlier run aside or starts anything)."""
    path = Path(directory) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return  # no lock file: no store, or one no merlion of this version ran on
    try:
        _flock_or_refuse(fd, fcntl.LOCK_SH, Path(directory))
    finally:
        os.close(fd)


@contextlib.contextmanager
def holding(directory: str | os.PathLike[str]) -> Iterator[None]:
    """Hold the store at ``directory`` for a moment without changing it (StoreInUse if a live process holds it):
    the demo moves an earlier run aside inside this, so no run can take that store while it is being moved. No
    lock file (no store, or one no merlion of this version ran on): nothing to hold, nothing created."""
    try:
        fd = os.open(Path(directory) / LOCK_FILE, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        _flock_or_refuse(fd, fcntl.LOCK_EX, Path(directory))
        yield
    finally:
        os.close(fd)


def _flock_or_refuse(fd: int, mode: int, directory: Path) -> None:
    """``flock`` without waiting; held by another process: StoreInUse naming it."""
    try:
        fcntl.flock(fd, mode | fcntl.LOCK_NB)
    except OSError as err:
        if err.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise
        raise in_use(directory) from None


def in_use(directory: Path) -> StoreInUse:
    """The one line a refused start prints: the store and who holds it (the pid its holder wrote)."""
    try:
        text = (directory / LOCK_FILE).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        text = ""
    who = f"pid {text}" if text.isdigit() else "another process"
    return StoreInUse(f"store {directory}: in use by {who} (a merlion run, demo or extension); stop it or use "
                      f"another store")
