"""Crash-safe file replacement: write a temp file, fsync it, rename it over the target, fsync the directory.

A crash at any moment leaves either the old file or the new one, whole. The temp file sits next to the target
(a rename is only atomic within one file system) and its name starts with ``TMP_PREFIX`` so that a store can
sweep up the ones a crash left behind.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

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
