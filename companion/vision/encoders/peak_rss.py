"""This process's own peak resident memory, the figure the companion's memory budget is about.

``getrusage().ru_maxrss`` is no good for it on Linux: it survives ``execve``, so a child process started by a
large one (the companion starting a torch child, pytest starting a measuring script) reports its parent's RSS at
the fork whenever that is higher than its own peak. ``VmHWM`` in /proc/self/status belongs to the new address
space only.
"""

from __future__ import annotations

import resource
import sys


def peak_rss_mb() -> float:
    """VmHWM in MB (Linux); elsewhere ru_maxrss (KiB on Linux, bytes on macOS)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0
