"""One bytes-per-second budget for everything the companion sends, with priorities.

A token bucket in wire bytes: it fills at ``rate`` up to a small ``capacity`` and every byte the link writes
drains it, including bytes the link sent on its own (its 1 Hz heartbeat, read from ``link.tx_bytes``). A queued
message goes only when the bucket holds a full frame (``MAX_WIRE``), and is then charged the bytes the link
reports it actually wrote: the budget never packs a message itself (packing mutates the message object, and a
second pack on another thread is how packets left corrupted), so the link's one send path packs each message
exactly once. Over any window W the wire carries at most ``rate * W + capacity + one message`` bytes; with the
default capacity (a tenth of a second, at least one frame) that is within 3% over 10 s. Queues are served by
priority, except that answers to requests (CONTROL) may not starve captures, status and thumbnails: while any
of those wait, answers get at most ``control_share`` of the bytes sent, counted in bytes on both sides (a turn
per message had let a 560-byte run of answers buy one 40-byte status line, so the thumbnail push behind the status
never went). Bulk sources (FTP bursts) are asked for a packet only when all queues above them are empty and the
budget allows, so a new burst never waits behind a stale one.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mav

log = logging.getLogger(__name__)

MAX_WIRE = 280
"""The largest MAVLink 2 frame (unsigned): 255 payload + 12 header/crc bytes, rounded up."""


class Priority(IntEnum):
    CONTROL = 0
    """Command answers, parameter replies."""
    STATUS = 1
    THUMBNAIL = 2
    BULK = 3
    """MAVLink FTP."""


class Link(Protocol):
    tx_bytes: int

    def send(self, msg: Any) -> int: ...


@dataclass
class _Item:
    msg: mav.MAVLink_message
    tag: Any


class LinkBudget:
    """Priority queues drained by one thread within ``rate`` bytes per second (see the module docstring)."""

    def __init__(self, link: Link, rate: float = 2000.0, *, clock: Callable[[], float] = time.monotonic,
                 capacity_s: float = 0.1, queue_limit: int = 4000, control_share: float = 0.5) -> None:
        self.link = link
        self._clock = clock
        self._capacity_s = capacity_s
        self._queues: dict[Priority, collections.deque[_Item]] = {p: collections.deque() for p in Priority}
        self._sources: list[tuple[Priority, Callable[[], mav.MAVLink_message | None]]] = []
        self._queue_limit = queue_limit
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.rate = float(rate)
        self._level = self.capacity
        self._last = clock()
        self._last_tx = link.tx_bytes
        self.sent_bytes = 0
        self.sent_by_priority = {p: 0 for p in Priority}
        self.dropped = 0
        self.control_share = control_share
        self._control_debt = 0.0
        """Answers' bytes beyond their share while STATUS or THUMBNAIL messages waited (> 0: those go first)."""
        self._history: collections.deque[tuple[float, int]] = collections.deque()

    @property
    def capacity(self) -> float:
        return max(MAX_WIRE, self.rate * self._capacity_s)

    def set_rate(self, rate: float) -> None:
        """Change the budget at once (a parameter change); the bucket is clamped to the new capacity."""
        with self._cond:
            self.rate = float(rate)
            self._level = min(self._level, self.capacity)
            self._cond.notify()

    # ---- queueing -------------------------------------------------------------------------------------------

    def submit(self, msg: mav.MAVLink_message, priority: Priority, *, tag: Any = None,
               replace: bool = False, unique: bool = False) -> bool:
        """Queue ``msg``; False when ``unique`` and a message with the same ``tag`` is still queued (a reply to a
        retransmitted request). ``replace`` drops queued messages with the same ``tag`` first (latest value wins)."""
        item = _Item(msg, tag)
        with self._cond:
            queue = self._queues[priority]
            if unique and tag is not None and any(i.tag == tag for i in queue):
                return False
            if replace and tag is not None:
                kept = [i for i in queue if i.tag != tag]
                self.dropped += len(queue) - len(kept)
                queue.clear()
                queue.extend(kept)
            if len(queue) >= self._queue_limit:
                queue.popleft()
                self.dropped += 1
            queue.append(item)
            self._cond.notify()
            return True

    def drop(self, tag: Any) -> int:
        """Remove every queued message carrying ``tag`` (a thumbnail whose frame left the summary)."""
        with self._cond:
            n = 0
            for queue in self._queues.values():
                kept = [i for i in queue if i.tag != tag]
                n += len(queue) - len(kept)
                queue.clear()
                queue.extend(kept)
            self.dropped += n
            return n

    def add_source(self, priority: Priority, pull: Callable[[], mav.MAVLink_message | None]) -> None:
        """``pull()`` is asked for one message whenever the budget has room and no queue above has work."""
        with self._cond:
            self._sources.append((priority, pull))

    def wake(self) -> None:
        """A source has new work."""
        with self._cond:
            self._cond.notify()

    def pending(self, priority: Priority | None = None) -> int:
        with self._cond:
            if priority is not None:
                return len(self._queues[priority])
            return sum(len(q) for q in self._queues.values())

    # ---- sending --------------------------------------------------------------------------------------------

    def _refill(self) -> None:
        now = self._clock()
        self._level = min(self.capacity, self._level + (now - self._last) * self.rate)
        self._last = now
        tx = self.link.tx_bytes
        foreign = tx - self._last_tx
        self._last_tx = tx
        if foreign > 0:  # the link's own heartbeat (our sends were already taken off)
            self._level -= foreign
            self._note(now, foreign)

    def _note(self, now: float, nbytes: int) -> None:
        self._history.append((now, nbytes))
        while self._history and self._history[0][0] < now - 10.0:
            self._history.popleft()

    def in_use_bps(self, window_s: float = 5.0) -> float:
        """Wire bytes per second over the last ``window_s`` seconds (at most 10)."""
        with self._cond:
            now = self._clock()
            total = sum(n for t, n in self._history if t >= now - window_s)
        return total / window_s

    def pump(self) -> float | None:
        """Send what the budget allows now; the seconds to wait before trying again (None: nothing to send)."""
        with self._cond:
            while True:
                self._refill()
                if not getattr(self.link, "connected", True):
                    return 0.2  # no peer yet (a UDP server before anyone spoke): keep the queue, lose nothing
                wait = self._send_one()
                if wait != 0.0:
                    return wait

    def _send_one(self) -> float | None:
        """0.0 after sending one message; else the wait the budget needs, or None when nothing is pending."""
        waiting = bool(self._queues[Priority.STATUS] or self._queues[Priority.THUMBNAIL])
        if not waiting:
            self._control_debt = 0.0
        for prio in Priority:
            if prio == Priority.CONTROL and waiting and self._control_debt > 0:
                continue  # answers used their share of the bytes: captures, status and thumbnails go first
            queue = self._queues[prio]
            if queue:
                if self._level < MAX_WIRE:
                    return max(0.001, (MAX_WIRE - self._level) / self.rate)
                self._send(prio, queue.popleft().msg, waiting)
                return 0.0
            for sprio, pull in self._sources:
                if sprio != prio:
                    continue
                if self._level < MAX_WIRE:
                    return max(0.001, (MAX_WIRE - self._level) / self.rate)
                msg = pull()
                if msg is not None:
                    self._send(prio, msg, waiting)
                    return 0.0
        return None

    def _send(self, prio: Priority, msg: mav.MAVLink_message, waiting: bool) -> None:
        """Write ``msg`` and charge it; ``waiting``: captures, status or thumbnails waited while it was chosen."""
        sent = self.link.send(msg)
        tx = self.link.tx_bytes
        foreign = tx - self._last_tx - sent  # a heartbeat that slipped in since the last look counts too
        self._last_tx = tx
        if foreign > 0:
            self._level -= foreign
            self._note(self._clock(), foreign)
        self._level -= sent
        if waiting:
            self._share(prio, sent)
        self.sent_bytes += sent
        self.sent_by_priority[prio] += sent
        self._note(self._clock(), sent)

    def _share(self, prio: Priority, sent: int) -> None:
        """Answers and the rest split the bytes ``control_share`` : 1 - ``control_share`` while both wait: an
        answer adds its bytes beyond its share to the debt, a status or thumbnail message pays it back (a long
        quiet spell of answers earns them no burst later: the credit is one frame at most)."""
        if prio == Priority.CONTROL:
            self._control_debt += sent * (1.0 - self.control_share)
        elif prio in (Priority.STATUS, Priority.THUMBNAIL):
            self._control_debt = max(-MAX_WIRE * self.control_share, self._control_debt - sent * self.control_share)

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="surface-budget", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._thread = None

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                wait = self.pump()
            except Exception:
                log.exception("link budget: send failed")
                wait = 0.1
            with self._cond:
                if self._stop.is_set():
                    return
                # a source with nothing to give is polled again soon; new submissions wake us at once
                self._cond.wait(0.05 if wait is None else min(max(wait, 0.001), 0.5))
