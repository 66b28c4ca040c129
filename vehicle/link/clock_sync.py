"""Map the autopilot's ``time_boot_ms`` onto the companion's clock, so telemetry and frames share one time line.

Every sample gives ``offset = arrival_time - time_boot``: the true offset plus a transport delay that is never
negative. The smallest offset over a sliding window is therefore the best estimate (jitter only ever makes a
packet late), and the window lets slow drift between the two clocks through. A reboot shows as ``time_boot``
going backwards: the window is cleared and the mapping starts again from the new boot. A run of samples all far
later than the estimate (a reboot after a silence longer than the last uptime, or a link that started buffering)
restarts the mapping too, counted as a resync.
"""

from __future__ import annotations

import threading
from collections import deque


class BootClock:
    """Estimate ``companion_time = time_boot_s + offset`` from (time_boot_ms, arrival time) pairs."""

    def __init__(self, window_s: float = 20.0, reboot_tolerance_s: float = 0.5, jump_samples: int = 5) -> None:
        self.window_s = window_s
        self.reboot_tolerance_s = reboot_tolerance_s
        self.jump_samples = jump_samples
        self.reboots = 0
        """Reboots seen as time_boot_ms going backwards."""
        self.resyncs = 0
        """Mapping restarts after a run of samples far later than the estimate."""
        self.samples = 0
        self._window: deque[tuple[float, float]] = deque()  # (arrival, offset), offsets increasing (min-queue)
        self._last_boot_s: float | None = None
        self._above = 0
        self._lock = threading.Lock()
        """observe() runs on the MAVLink thread while frames are tagged on the inference thread: the window is
        briefly empty inside observe() (popped before the new minimum goes in), which a reader must never see."""

    @property
    def synced(self) -> bool:
        with self._lock:
            return bool(self._window)

    @property
    def offset(self) -> float | None:
        """Seconds to add to the autopilot's boot time to get companion time (None before the first sample)."""
        with self._lock:
            return self._window[0][1] if self._window else None

    def observe(self, time_boot_ms: int, arrival: float) -> bool:
        """Take one sample; True when it revealed an autopilot reboot (the mapping was restarted)."""
        with self._lock:
            return self._observe(time_boot_ms, arrival)

    def _observe(self, time_boot_ms: int, arrival: float) -> bool:
        boot_s = time_boot_ms / 1000.0
        offset = arrival - boot_s
        rebooted = self._last_boot_s is not None and boot_s < self._last_boot_s - self.reboot_tolerance_s
        if rebooted:
            self.reboots += 1
            self._restart()
        elif self._window and offset > self._window[0][1] + self.reboot_tolerance_s:
            # far later than expected: one late packet is jitter, a run of them means the mapping moved (a reboot
            # after a silence longer than the last uptime, or a link that now buffers): start again from here
            self._above += 1
            if self._above < self.jump_samples:
                return False
            self.resyncs += 1
            self._restart()
        else:
            self._above = 0
        self._last_boot_s = boot_s
        self.samples += 1
        while self._window and self._window[-1][1] >= offset:
            self._window.pop()
        self._window.append((arrival, offset))
        while len(self._window) > 1 and self._window[0][0] < arrival - self.window_s:
            self._window.popleft()
        return rebooted

    def _restart(self) -> None:
        self._window.clear()
        self._above = 0

    def to_local(self, time_boot_ms: int) -> float | None:
        """The companion time of an autopilot timestamp (None until synced)."""
        offset = self.offset
        return None if offset is None else time_boot_ms / 1000.0 + offset
