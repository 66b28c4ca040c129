"""sd_notify: tell systemd we are ready, still alive (watchdog) and what we are doing, and nothing outside it.

systemd passes the socket in ``$NOTIFY_SOCKET`` (a path, or ``@name`` for the abstract namespace) and the
watchdog period in ``$WATCHDOG_USEC``. Outside systemd neither is set and every call does nothing, so the same
code runs from a terminal. The socket is injectable so tests use a real AF_UNIX datagram socket.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


class Notifier:
    """One datagram per message; failures are logged once and never raised (systemd may be restarting)."""

    def __init__(self, address: str | None, *, watchdog_s: float | None = None,
                 sock: socket.socket | None = None) -> None:
        self.address = address
        self.watchdog_s = watchdog_s
        self.sent: int = 0
        self._warned = False
        self._sock = sock
        if address and sock is None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)

    @classmethod
    def from_environ(cls, environ: Mapping[str, str]) -> Notifier:
        """Built from the process environment the command line passes in (only it reads os.environ)."""
        address = environ.get("NOTIFY_SOCKET") or None
        watchdog_s = None
        usec = environ.get("WATCHDOG_USEC")
        pid = environ.get("WATCHDOG_PID")
        if usec and usec.isdigit() and (not pid or pid == str(os.getpid())):
            watchdog_s = int(usec) / 1e6
        return cls(address, watchdog_s=watchdog_s)

    @property
    def enabled(self) -> bool:
        return bool(self.address)

    @property
    def ping_interval_s(self) -> float | None:
        """systemd's advice: ping at half the watchdog period."""
        return self.watchdog_s / 2 if self.watchdog_s else None

    def notify(self, *fields: str) -> bool:
        if not self.address or self._sock is None:
            return False
        target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            self._sock.sendto("\n".join(fields).encode(), target)
        except OSError as err:
            if not self._warned:
                log.warning("sd_notify to %s failed: %s", self.address, err)
                self._warned = True
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1", *([f"STATUS={status}"] if status else []))

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text[:200]}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
