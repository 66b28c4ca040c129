"""How many requests each requester may make: a token bucket per (system, component, signed) on the receive loop.

A ground station asks a few things a second (a parameter download is one PARAM_REQUEST_LIST and some re-reads; camera
discovery a handful of commands); a sender far above that is flooding. Its excess requests are dropped before any
work is done for them, counted, and reported once per requester (``on_flood``), never per packet. Signed requesters
get a larger allowance than unsigned ones, and spoofed ids by the thousand share one bucket.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from vehicle.link.fair_replies import OVERFLOW, Requester

UNSIGNED_PER_S = 10.0
SIGNED_PER_S = 50.0
BURST_S = 2.0
"""A requester may ask this many seconds' worth at once."""


class RequestGate:
    """``admit(who)``: whether ``who`` may be answered now (see the module docstring)."""

    def __init__(self, *, unsigned_per_s: float = UNSIGNED_PER_S, signed_per_s: float = SIGNED_PER_S,
                 max_requesters: int = 256, on_flood: Callable[[Requester], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rates = {False: unsigned_per_s, True: signed_per_s}
        self.max_requesters = max_requesters
        self._on_flood = on_flood
        self._clock = clock
        self._lock = threading.Lock()
        self._buckets: dict[Requester, list[float]] = {}
        self.dropped: dict[Requester, int] = {}

    def admit(self, who: Requester) -> bool:
        flood = False
        with self._lock:
            if who not in self._buckets and len(self._buckets) >= self.max_requesters and not who[2]:
                who = OVERFLOW
            rate = self.rates[who[2]]
            now = self._clock()
            bucket = self._buckets.setdefault(who, [rate * BURST_S, now])
            bucket[0] = min(rate * BURST_S, bucket[0] + (now - bucket[1]) * rate)
            bucket[1] = now
            if bucket[0] >= 1.0:
                bucket[0] -= 1.0
                return True
            count = self.dropped.get(who, 0) + 1
            self.dropped[who] = count
            flood = count == 1
        if flood and self._on_flood is not None:
            self._on_flood(who)
        return False

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {f"{s}/{c}{'' if signed else ' unsigned'}": n for (s, c, signed), n in self.dropped.items()}
