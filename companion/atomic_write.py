"""Crash-safe file replacement: write a temp file, fsync it, rename it over the target, fsync the directory.

A crash at any moment leaves either the old file or the new one, whole. The temp file sits next to the target
(a rename is only atomic within one file system) and its name starts with ``TMP_PREFIX`` so that a store can
sweep up the ones a crash left behind.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

from companion.errors import MerlionError

TMP_PREFIX = ".tmp-"


def atomic_write(path: Path, data: bytes | str) -> None:
    """Replace ``path`` with ``data`` (str is written as UTF-8) so that it is never seen half-written."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = path.with_name(f"{TMP_PREFIX}{path.name}.{os.getpid()}.{threading.get_ident()}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise
    fsync_dir(path.parent)


def check_target(path: str | Path) -> Path:
    """``path`` if a file can be written there later, else a one-line MerlionError naming why: called before long
    work (training, encoding), so that a mistyped output path fails at once instead of after it."""
    p = Path(path)
    if p.is_dir():
        raise MerlionError(f"{p}: is a folder (give the file's name)")
    existing = next((a for a in (p.parent, *p.parent.parents) if a.exists()), Path("."))
    if not existing.is_dir():
        raise MerlionError(f"{p}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK):
        raise MerlionError(f"{p}: {existing} is not writable")
    return p


def fsync_dir(directory: Path) -> None:
    """Make a rename durable: the directory entry itself must reach the disk (best effort)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
