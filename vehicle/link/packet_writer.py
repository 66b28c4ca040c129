"""The one thread that writes a link's packets, in the order they were handed over.

pymavlink's ``pack`` writes into the message object and the link's sequence number must leave in order, so every
outgoing packet is packed and written on this one thread; a sender waits for its own packet and gets the bytes it
became, with which budgets charge what was really sent. A stalled serial port holds up no sender for more than
``SEND_WAIT_S``.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

SEND_WAIT_S = 2.0
_POLL_S = 0.1

Item = TypeVar("Item")


@dataclass
class _Outgoing(Generic[Item]):
    """One packet handed to the writer thread, and how many bytes it became."""

    item: Item
    done: threading.Event = field(default_factory=threading.Event)
    sent: int = 0


class PacketWriter(Generic[Item]):
    """Hands items to ``write`` (which packs and writes one, returning the bytes written) on its own thread."""

    def __init__(self, write: Callable[[Item], int], name: str) -> None:
        self._write = write
        self.name = name
        self._cond = threading.Condition()
        self._outbox: collections.deque[_Outgoing[Item]] = collections.deque()
        self._thread: threading.Thread | None = None
        self._stopping = False

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stopping = False
        self._thread = threading.Thread(target=self._loop, name=self.name, daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Write what was handed over, then end the thread; later items are written on the caller's thread."""
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
        self._thread = None

    def send(self, item: Item) -> int:
        """Write ``item`` on the writer thread and wait for it; the bytes written (0 if it took over SEND_WAIT_S:
        the packet may still go, and is counted then)."""
        thread = self._thread
        job = _Outgoing(item)
        with self._cond:  # decided under the lock that stop() takes: a job is queued only while the loop runs
            queued = thread is not None and threading.current_thread() is not thread and not self._stopping
            if queued:
                self._outbox.append(job)
                self._cond.notify()
        if not queued:
            return self._write(item)  # not started, stopping, or the writer itself: no thread to wait for
        if not job.done.wait(SEND_WAIT_S):
            return 0
        return job.sent

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._outbox and not self._stopping:
                    self._cond.wait(_POLL_S)
                if not self._outbox:
                    return
                job = self._outbox.popleft()
            job.sent = self._write(job.item)
            job.done.set()
