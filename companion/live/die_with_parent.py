"""Start a command that dies with the process that started it, even when that one is killed with SIGKILL.

``merlion demo`` runs the simulator and the surface tool as child processes in their own session (so a Ctrl-C in
the terminal reaches only the demo, which then stops them in order). A demo killed with SIGKILL cannot stop
anything, so each child asks the kernel for a signal when its parent goes: Linux's PR_SET_PDEATHSIG. It is set
here, in a tiny launcher that then ``exec``s the real command (the setting survives exec), rather than in
``preexec_fn``, which is unsafe in a process with threads (the demo has several).

Run as ``python -m companion.live.die_with_parent PARENT_PID -- COMMAND...``; ``command`` builds that line.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1
"""From <linux/prctl.h>."""


def command(args: list[str], *, parent: int | None = None) -> list[str]:
    """The launcher line for ``args``: the command dies with ``parent`` (default: this process)."""
    return [sys.executable, "-m", __name__, str(parent or os.getpid()), "--", *args]


def set_parent_death_signal(sig: int = signal.SIGTERM) -> bool:
    """Ask Linux for ``sig`` when the parent exits; False where the kernel has no such thing."""
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[1] != "--" or not argv[0].isdigit():
        print("usage: python -m companion.live.die_with_parent PARENT_PID -- COMMAND...", file=sys.stderr)
        return 2
    parent, args = int(argv[0]), argv[2:]
    if not set_parent_death_signal():
        print(f"die_with_parent: no parent-death signal on {sys.platform}; {args[0]} may outlive its parent",
              file=sys.stderr)
    if os.getppid() != parent:
        return 1  # the parent died before the signal was set: nobody would stop this command
    os.execv(args[0], args)
    return 0  # not reached: exec replaced this process


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
