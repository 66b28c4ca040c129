"""The companion's boot clock (MAVLink ``time_boot_ms``) mapped onto this computer's clock.

The depth track on the surface page was drawn at the time each MRL_DEPTH value *arrived*: up to a status period
after the companion measured it, plus the wait in its link budget behind thumbnails, so during a descent the
summary dots (placed at their capture time, with the depth at that time) sat about 2 s off the track. Each
message carries the companion's boot time of its making; the smallest ``arrival - time_boot_ms`` seen is the
offset with the least delay in it (the usual minimum-delay estimate), so ``time_boot_ms + offset`` is when the
value was measured, to within the fastest message's latency.
"""

from __future__ import annotations

from collections import deque

WINDOW_S = 120.0
"""Offsets of the messages that arrived in the last two minutes are kept: old ones age out, so a drift between the
two clocks is followed, and a slow stretch of the link does not stay in the estimate."""


MAX_KEPT = 4096
"""Offsets kept at most, however many messages a window holds."""


class BootClock:
    """Feed ``local(time_boot_ms, arrival)`` every companion message with a boot time; it returns the local time."""

    def __init__(self, window_s: float = WINDOW_S) -> None:
        self.window_s = window_s
        self._offsets: deque[tuple[float, float]] = deque(maxlen=MAX_KEPT)
        """(arrival, offset), offsets rising from the front: the front is the window's minimum (a later message
        with a smaller offset makes the larger ones before it useless, so they go). Before, every offset of the
        window was kept and scanned per message: a companion sending 40,000 values within two minutes cost the
        receive loop 23 s, and the memory grew with the rate."""
        self._last_ms: int | None = None

    def local(self, time_boot_ms: int, arrival: float) -> float:
        """The local time at which the companion's clock read ``time_boot_ms``."""
        if self._last_ms is not None and time_boot_ms + 5000 < self._last_ms:  # the companion restarted
            self._offsets.clear()
        self._last_ms = time_boot_ms
        offset = arrival - time_boot_ms / 1000.0
        while self._offsets and self._offsets[-1][1] >= offset:
            self._offsets.pop()
        self._offsets.append((arrival, offset))
        while self._offsets[0][0] < arrival - self.window_s:
            self._offsets.popleft()
        return time_boot_ms / 1000.0 + self._offsets[0][1]
