"""A bounded queue that drops the OLDEST item when full, and counts what it dropped.

Between capture and inference the newest frame is the one worth having: when inference falls behind, waiting
frames go stale, so they are the ones to lose. Nothing ever queues without bound.

Items may be of two weights (``light``): between capture and inference a frame the gate skipped carries no
pixels and needs no encoder time, so it is bounded apart (``light_max``, generous) from the frames waiting to be
encoded (``maxsize``, a fraction of a second of backlog), and ``get_batch`` counts only the heavy ones toward a
batch: at 1080p60 with the gate on, a queue of four frames of either kind dropped 6.8% of them while the encoder
ran one batch, though the gate let through far fewer frames than the encoder could take.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")

LIGHT_PER_BATCH = 16
"""Light items ``get_batch`` takes at most per heavy one asked for: bounded even when the gate skips everything."""


class DropOldestQueue(Generic[T]):
    def __init__(self, maxsize: int, *, light: Callable[[T], bool] | None = None, light_max: int = 0) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self.maxsize = maxsize
        self.light = light
        """Which items are light (None: every item is heavy, one bound for all)."""
        self.light_max = max(1, light_max)
        self.dropped = 0
        self.put_count = 0
        self._items: deque[T] = deque()
        self._heavy = 0
        self._cond = threading.Condition()
        self._closed = False

    def _is_light(self, item: T) -> bool:
        return self.light is not None and self.light(item)

    def _drop_oldest(self, light: bool) -> None:
        for i, item in enumerate(self._items):
            if self._is_light(item) == light:
                del self._items[i]
                self.dropped += 1
                return

    def put(self, item: T) -> bool:
        """Add ``item``; returns False when an older item (of its weight) had to make room for it."""
        with self._cond:
            light = self._is_light(item)
            self._items.append(item)
            self._heavy += not light
            self.put_count += 1
            room = True
            if light and len(self._items) - self._heavy > self.light_max:
                self._drop_oldest(True)
                room = False
            elif not light and self._heavy > self.maxsize:
                self._drop_oldest(False)
                self._heavy -= 1
                room = False
            self._cond.notify()
            return room

    def get_batch(self, max_items: int, timeout: float) -> list[T]:
        """Up to ``max_items`` waiting heavy items (and the light ones among them, ``LIGHT_PER_BATCH`` times as
        many at most), oldest first; waits at most ``timeout`` for the first one."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            out: list[T] = []
            heavy = 0
            while self._items and heavy < max_items and len(out) < max_items * LIGHT_PER_BATCH:
                item = self._items.popleft()
                if not self._is_light(item):
                    heavy += 1
                    self._heavy -= 1
                out.append(item)
            return out

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
