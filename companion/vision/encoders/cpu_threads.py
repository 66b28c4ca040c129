"""How many compute threads an encoder takes: one per core this process may run on, or ``OMP_NUM_THREADS``.

Written once, without torch, for both runtimes: the torch encoders (``torch_runtime.configure_threads``) and the
ONNX Runtime one (``onnx_clip``), which must start without importing torch.
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)


def usable_cores() -> int:
    """The cores this process may run on (its affinity, e.g. a container's or a systemd unit's CPU set)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def intra_op_threads() -> int:
    """``OMP_NUM_THREADS`` where it is set to a positive whole number (the usual way to share a host's cores
    between processes: the camera server, a second encoder, test workers), else one per usable core."""
    wanted = os.environ.get("OMP_NUM_THREADS", "").strip()
    if wanted.isdecimal() and wanted.isascii() and int(wanted) > 0:
        return int(wanted)
    if wanted:
        log.warning("OMP_NUM_THREADS=%r is not a positive whole number: one thread per core", wanted)
    return usable_cores()
