"""How many warnings about strangers reach the surface (or a flood's lines the log): a small bucket, so that many
sources, or a fast one, cannot flood the downlink or the disk.

Every STATUSTEXT about a refused or flooding stranger costs the same downlink budget as a capture and is one more
line in QGroundControl. Made-up sender ids are free, so a warning per source would let one device on the tether send
hundreds; the bucket lets a burst through and then one per refill period (the count of what was refused stays in
the statistics and the log).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

WARN_BURST = 5
WARN_REFILL_S = 10.0


class WarningBucket:
    """A token bucket of ``burst`` warnings, one more every ``refill_s`` seconds; thread-safe."""

    def __init__(self, burst: int = WARN_BURST, refill_s: float = WARN_REFILL_S, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.burst = burst
        self.refill_s = refill_s
        self._clock = clock
        self._tokens = float(burst)
        self._at = clock()
        self._lock = threading.Lock()

    def take(self) -> bool:
        """True when one more warning may be sent now."""
        with self._lock:
            now = self._clock()
            self._tokens = min(self.burst, self._tokens + (now - self._at) / self.refill_s)
            self._at = now
            if self._tokens < 1:
                return False
            self._tokens -= 1
            return True
