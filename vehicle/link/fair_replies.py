"""Answers to requests, shared fairly between the requesters on one downlink.

Every ground station (and every stranger on the tether) that asks something gets its replies queued under its own
name: (system, component, whether its request was signed). The budget's sender pulls one reply at a time
(``next``): signed requesters first, then unsigned ones, each tier in deficit round robin (turns counted in bytes,
so a requester of large replies gets no more of the link than one of small ones). Unsigned requesters all together
draw on ONE byte bucket, ``UnsignedSlice`` (a share of the link's rate): ids are free to make up, so a slice per id
had let 200 made-up ids ask for 200 shares, and the captures and thumbnails below (``LinkBudget``) lost the link.
An unsigned FTP burst (a file read streamed without a request per chunk) is not a reply here: it takes only the
bulk bytes left after signed bursts and the queued replies (``Downlink``, ``FtpServer.next_burst``).
A requester's queue holds at most ``per_requester`` replies; what does not fit is dropped and counted, and the first
drop for a requester is reported once (``on_flood``), never per packet. A requester that asked nothing for
``quiet_s`` has gone (a flood that stopped, a ground station closed): its queued replies expire and it leaves the
table, so nothing is sent for it afterwards and new requesters find room.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

Requester = tuple[int, int, bool]
"""(system id, component id, signed)."""
OVERFLOW: Requester = (0, 0, False)
"""Unsigned requesters beyond ``max_requesters`` share this one queue (spoofed ids cannot grow the table)."""
QUIET_S = 5.0
"""A requester that asked nothing for this long has gone: its queued replies expire. A client waiting for its
answers asks again within a few seconds (QGroundControl re-reads a missing parameter after 1 s, an FTP client
retransmits after 0.5-2 s)."""
QUANTUM = 280
"""Bytes a requester may send per round: a whole frame, so every requester sends at least one reply per round."""
_HEADER = 12
_SIGNATURE = 13


def wire_estimate(msg: Any) -> int:
    """The bytes ``msg`` will take on the wire (payload, header and checksum, and a signature's worth)."""
    unpacker = getattr(msg, "unpacker", None)
    return (unpacker.size if unpacker is not None else 255) + _HEADER + _SIGNATURE


class UnsignedSlice:
    """The one byte bucket every unsigned requester's replies draw on: ``share`` of the link's rate, half a
    second's worth at most (a frame at least)."""

    def __init__(self, rate: Callable[[], float], *, share: float = 0.25,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._rate = rate
        self.share = share
        self._clock = clock
        self._lock = threading.Lock()
        self._tokens = self._burst()
        self._at = clock()
        self.sent = 0

    def _burst(self) -> float:
        return max(float(QUANTUM), self._rate() * self.share * 0.5)

    def take(self, cost: int) -> bool:
        """Charge ``cost`` bytes if the slice holds them."""
        with self._lock:
            now = self._clock()
            self._tokens = min(self._burst(), self._tokens + (now - self._at) * self._rate() * self.share)
            self._at = now
            if self._tokens < cost:
                return False
            self._tokens -= cost
            self.sent += cost
            return True


@dataclass
class _Queue:
    heard: float
    items: collections.deque = field(default_factory=collections.deque)
    deficit: float = 0.0
    dropped: int = 0
    sent: int = 0


class FairReplies:
    """Per-requester reply queues drained signed-first, in byte-fair turns (see the module docstring)."""

    def __init__(self, unsigned: UnsignedSlice, *, per_requester: int = 64, max_requesters: int = 64,
                 on_flood: Callable[[Requester], None] | None = None, work_conserving: bool = False,
                 quiet_s: float = QUIET_S, clock: Callable[[], float] = time.monotonic) -> None:
        """``unsigned``: the slice unsigned replies draw on (one object may serve several queues: the link has one
        slice). ``work_conserving``: an unsigned reply beyond the slice is still sent when nobody else waits (for
        bulk transfers, which only use what the link has left)."""
        self.unsigned = unsigned
        self.work_conserving = work_conserving
        self.per_requester = per_requester
        self.max_requesters = max_requesters
        self.quiet_s = quiet_s
        self._on_flood = on_flood
        self._clock = clock
        self._lock = threading.Lock()
        self._queues: dict[Requester, _Queue] = {}
        self._turn: dict[bool, collections.deque[Requester]] = {True: collections.deque(),
                                                               False: collections.deque()}
        self._swept = clock()
        self.dropped = 0
        self.expired = 0
        """Replies dropped because their requester went quiet before they could be sent."""
        self.floods: list[Requester] = []
        """Requesters whose replies were dropped, in the order they first were (each reported once; at most
        ``max_requesters`` unsigned ones are named, the rest are reported as ``OVERFLOW``)."""

    def submit(self, who: Requester, msgs: list[Any], *, tag: Any = None, unique: bool = False) -> int:
        """Queue ``msgs`` for ``who``; how many were queued. With ``unique``, nothing is queued while a reply with
        the same ``tag`` still waits (a repeated PARAM_REQUEST_LIST, a retransmitted FTP request)."""
        flood = False
        with self._lock:
            now = self._clock()
            self._sweep(now)  # quiet requesters make room first
            if who not in self._queues and not who[2] and self._unsigned_count() >= self.max_requesters:
                who = OVERFLOW
            queue = self._queues.get(who)
            if queue is None:
                queue = self._queues[who] = _Queue(heard=now)
                self._turn[who[2]].append(who)
            queue.heard = now
            if unique and tag is not None and any(t == tag for t, _ in queue.items):
                return 0
            room = max(0, self.per_requester - len(queue.items))
            for msg in msgs[:room]:
                queue.items.append((tag, msg))
            lost = len(msgs) - min(room, len(msgs))
            if lost:
                queue.dropped += lost
                self.dropped += lost
                named = who if who[2] or sum(not f[2] for f in self.floods) < self.max_requesters else OVERFLOW
                if named not in self.floods:
                    self.floods.append(named)
                    flood, who = True, named
        if flood and self._on_flood is not None:
            self._on_flood(who)
        return min(room, len(msgs))

    def next(self) -> Any | None:
        """The next reply to send (signed requesters first, unsigned ones within their slice), or None."""
        with self._lock:
            self._sweep(self._clock())
            for signed in (True, False):
                who = self._pick(signed)
                if who is None:
                    continue
                queue = self._queues[who]
                cost = wire_estimate(queue.items[0][1])
                if not signed and not self.unsigned.take(cost):
                    if self.work_conserving:
                        break  # the slice is spent: served below only if the link has nothing else
                    return None
                return self._pop(queue, cost)
            if self.work_conserving:
                who = self._pick(False)
                if who is not None:
                    queue = self._queues[who]
                    return self._pop(queue, wire_estimate(queue.items[0][1]))
            return None

    def pending(self) -> int:
        with self._lock:
            return sum(len(q.items) for q in self._queues.values())

    def stats(self) -> dict[str, object]:
        with self._lock:
            return {"pending": sum(len(q.items) for q in self._queues.values()), "dropped": self.dropped,
                    "expired": self.expired, "requesters": len(self._queues),
                    "flooding": [f"{s}/{c}{'' if signed else ' unsigned'}" for s, c, signed in self.floods]}

    def _unsigned_count(self) -> int:
        return len(self._turn[False])

    def _pick(self, signed: bool) -> Requester | None:
        """Deficit round robin: the next requester of the tier whose byte allowance covers its next reply."""
        turn = self._turn[signed]
        for _ in range(2 * len(turn) + 1):
            if not turn:
                return None
            who = turn[0]
            queue = self._queues[who]
            if not queue.items:
                queue.deficit = 0.0  # an idle requester saves nothing up
                turn.rotate(-1)
                continue
            if queue.deficit >= wire_estimate(queue.items[0][1]):
                return who
            queue.deficit += QUANTUM
            turn.rotate(-1)
        return None

    def _pop(self, queue: _Queue, cost: int) -> Any:
        queue.deficit -= cost
        queue.sent += 1
        return queue.items.popleft()[1]

    def _sweep(self, now: float) -> None:
        """Requesters quiet for ``quiet_s`` leave the table, their queued replies expired (twice a second)."""
        if now - self._swept < 0.5:
            return
        self._swept = now
        for who, queue in list(self._queues.items()):
            if now - queue.heard > self.quiet_s:
                self.expired += len(queue.items)
                del self._queues[who]
                self._turn[who[2]].remove(who)
