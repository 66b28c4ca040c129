"""Rate control shared by file sources: keep frames at a target rate, and optionally play them in real time."""

from __future__ import annotations

import time


class RateSubsampler:
    """Keeps the frames whose timestamps fall on a grid of ``1 / fps`` seconds from the first kept frame.

    A 10 fps source at ``fps=5`` keeps every second frame; a source slower than ``fps`` keeps every frame.
    Source indices and timestamps are untouched, so a kept frame can always be traced back.
    """

    def __init__(self, fps: float) -> None:
        if fps <= 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.period = 1.0 / float(fps)
        self._next: float | None = None

    def keep(self, time_s: float) -> bool:
        eps = 1e-6
        if self._next is None:
            self._next = time_s + self.period
            return True
        if time_s + eps < self._next:
            return False
        while self._next <= time_s + eps:
            self._next += self.period
        return True


class Pacer:
    """Sleeps so that frames come out at their source time, as a camera would deliver them (``realtime``)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._origin: float | None = None

    def wait(self, time_s: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self._origin is None:
            self._origin = now - time_s
        delay = self._origin + time_s - now
        if delay > 0:
            time.sleep(delay)
