"""Hand the C heap's free pages back to the OS, so that RSS (the companion's memory budget) drops with them.

Torch-free on purpose: the ONNX Runtime encoder calls it too, in a process that never imports torch.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc


def release_freed_memory() -> None:
    """Collect, then glibc's ``malloc_trim(0)``.

    Freeing a tower or an ONNX session's build buffers leaves hundreds of MB in glibc's heap that RSS keeps
    counting. Elsewhere (musl, macOS) only the collection happens.
    """
    gc.collect()
    name = ctypes.util.find_library("c")
    try:
        trim = ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        trim = None
    if trim is not None:
        trim(0)
