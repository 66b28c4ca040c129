"""Why an MP4 will not open: a recording cut short before its index was written.

An MP4/MOV keeps its index (the ``moov`` atom: where every frame is, how long it is) in one place; most
recorders write it last, when the recording is closed. A recording cut short (power lost, a full disk, the
vehicle's process killed) then holds the frames but no index, and no decoder can open it. Walking the top-level
atoms tells that case apart from a file that is simply not a video, so the error can say what happened and how to
recover (a tool such as untrunc rebuilds the index from a good recording of the same camera; .mkv or .ts
recordings stay readable when cut short).
"""

from __future__ import annotations

import struct
from pathlib import Path


def missing_mp4_index(path: Path) -> bool:
    """True when ``path`` starts as an MP4/MOV (an ``ftyp`` atom) and its top-level atoms hold no ``moov``."""
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(8)
            if len(head) < 8 or head[4:8] != b"ftyp":
                return False
            offset = 0
            while offset + 8 <= size:
                f.seek(offset)
                header = f.read(16)
                length, kind = struct.unpack(">I4s", header[:8])
                if kind == b"moov":
                    return False
                if length == 1 and len(header) == 16:  # 64-bit size follows
                    length = struct.unpack(">Q", header[8:16])[0]
                elif length == 0:  # this atom runs to the end of the file
                    break
                if length < 8:
                    break
                offset += length
    except OSError:
        return False
    return True


def no_index_message(path: Path) -> str:
    return (f"{path}: cannot be opened as a video: an MP4 without its index (no 'moov' atom), as a recording cut "
            f"short leaves it (the index is written last); its frames may be recovered with a tool such as untrunc "
            f"and a good recording from the same camera; record to .mkv or .ts, which stay readable when cut short")
