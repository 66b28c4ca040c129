"""A ground station's ear: a UDP socket on 127.0.0.1 that parses whatever MAVLink reaches it, stamped on arrival.

What the surface would receive, seen from the outside: the soak benchmark measures capture-to-surface latency with
it and the live tests wait on what the companion says. Written once here (product code cannot import from tests).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterable

from pymavlink.dialects.v20 import ardupilotmega as mav

_POLL_S = 0.2


class GroundListener:
    """Receives on its own thread; ``port`` is where a hub or link should send. Every parsed message gets
    ``received_at`` (wall-clock seconds, as MAVLink's time_utc) and is kept in ``messages``, or only those of
    ``types`` (a long run keeps what it measures, not every heartbeat)."""

    def __init__(self, types: Iterable[str] | None = None) -> None:
        self.types = frozenset(types) if types is not None else None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(_POLL_S)
        self.port: int = self.sock.getsockname()[1]
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        self.messages: list[mav.MAVLink_message] = []
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="ground-listener", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65535)
            except (TimeoutError, OSError):
                continue
            now = time.time()
            try:
                msgs = self.parser.parse_buffer(data) or []
            except mav.MAVError:
                continue
            with self._cond:
                for m in msgs:
                    if self.types is None or m.get_type() in self.types:
                        m.received_at = now
                        self.messages.append(m)
                self._cond.notify_all()

    def of_type(self, kind: str) -> list[mav.MAVLink_message]:
        with self._cond:
            return [m for m in self.messages if m.get_type() == kind]

    def texts(self) -> list[str]:
        """The STATUSTEXT lines received, as text."""
        return [m.text if isinstance(m.text, str) else m.text.decode(errors="replace")
                for m in self.of_type("STATUSTEXT")]

    def wait_for(self, predicate: Callable[[mav.MAVLink_message], bool], timeout: float = 60.0,
                 what: str = "message") -> mav.MAVLink_message:
        """The first kept message for which ``predicate`` holds; AssertionError naming ``what`` after ``timeout``."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for m in self.messages:
                    if predicate(m):
                        return m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {what} within {timeout} s")
                self._cond.wait(min(left, 0.5))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()
