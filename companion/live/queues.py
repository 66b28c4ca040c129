"""A bounded queue that drops the OLDEST item when full, and counts what it dropped.

Between capture and inference the newest frame is the one worth having: when inference falls behind, waiting
frames go stale, so they are the ones to lose. Nothing ever queues without bound.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class DropOldestQueue(Generic[T]):
    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self.maxsize = maxsize
        self.dropped = 0
        self.put_count = 0
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False

    def put(self, item: T) -> bool:
        """Add ``item``; returns False when an older item had to make room for it."""
        with self._cond:
            room = True
            if len(self._items) >= self.maxsize:
                self._items.popleft()
                self.dropped += 1
                room = False
            self._items.append(item)
            self.put_count += 1
            self._cond.notify()
            return room

    def get_batch(self, max_items: int, timeout: float) -> list[T]:
        """Up to ``max_items`` waiting items, oldest first; waits at most ``timeout`` for the first one."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            out: list[T] = []
            while self._items and len(out) < max_items:
                out.append(self._items.popleft())
            return out

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
