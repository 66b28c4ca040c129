"""Whether a command will be able to write its output file, asked before its long work starts.

A mistyped ``--out`` (a folder, a path under a file, a read-only place) should fail in one line at once, not after
minutes of encoding and training with nothing saved.
"""

from __future__ import annotations

import os
from pathlib import Path

from companion.errors import MerlionError


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
