"""Per-stage progress timestamps: a stage that stops making progress stops the watchdog pings.

Each loop calls ``beat(stage)`` whenever it does useful work or is legitimately idle (a queue was empty, the
source ended). If any required stage has not beaten for ``stall_after_s``, the companion is stuck: systemd's
watchdog is left to fire and restart it, and the MAVLink heartbeat says the same.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class Health:
    def __init__(self, stall_after_s: float, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.stall_after_s = stall_after_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._lock = threading.Lock()

    def register(self, stage: str) -> None:
        """A stage that must keep beating from now on."""
        with self._lock:
            self._last[stage] = self._clock()

    def beat(self, stage: str) -> None:
        with self._lock:
            self._last[stage] = self._clock()

    def forget(self, stage: str) -> None:
        """A stage that ended on purpose (its thread finished) no longer counts."""
        with self._lock:
            self._last.pop(stage, None)

    def stuck(self) -> list[str]:
        now = self._clock()
        with self._lock:
            return sorted(s for s, t in self._last.items() if now - t > self.stall_after_s)

    def healthy(self) -> bool:
        return not self.stuck()

    def ages(self) -> dict[str, float]:
        now = self._clock()
        with self._lock:
            return {s: round(now - t, 2) for s, t in self._last.items()}
