"""Answers to requests, shared fairly between the requesters on one downlink.

Every ground station (and every stranger on the tether) that asks something gets its replies queued under its own
name: (system, component, whether its request was signed). The budget's sender pulls one reply at a time
(``next``): signed requesters first, each in turn, then unsigned ones in turn, each unsigned requester within
``unsigned_share`` of the link's rate. A requester's queue holds at most ``per_requester`` replies; what does not
fit is dropped and counted, and the first drop for a requester is reported once (``on_flood``), never per packet.
So a PARAM_REQUEST_LIST flood from an unsigned sender costs it a bounded share of the link, not the signed
operator's answers, and never the captures and status below (the budget caps this tier, ``LinkBudget``).
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
_HEADER = 12
_SIGNATURE = 13


def wire_estimate(msg: Any) -> int:
    """The bytes ``msg`` will take on the wire (payload, header and checksum, and a signature's worth)."""
    unpacker = getattr(msg, "unpacker", None)
    return (unpacker.size if unpacker is not None else 255) + _HEADER + _SIGNATURE


@dataclass
class _Queue:
    items: collections.deque = field(default_factory=collections.deque)
    tokens: float = 0.0
    at: float = 0.0
    dropped: int = 0
    sent: int = 0


class FairReplies:
    """Per-requester reply queues drained signed-first, round robin (see the module docstring)."""

    def __init__(self, rate: Callable[[], float], *, unsigned_share: float = 0.25, per_requester: int = 64,
                 max_requesters: int = 64, on_flood: Callable[[Requester], None] | None = None,
                 work_conserving: bool = False, clock: Callable[[], float] = time.monotonic) -> None:
        """``work_conserving``: an unsigned requester over its share is still served when nobody else waits (for
        bulk transfers, which only use what the link has left)."""
        self._rate = rate
        self.work_conserving = work_conserving
        self.unsigned_share = unsigned_share
        self.per_requester = per_requester
        self.max_requesters = max_requesters
        self._on_flood = on_flood
        self._clock = clock
        self._lock = threading.Lock()
        self._queues: dict[Requester, _Queue] = {}
        self._turn: dict[bool, collections.deque[Requester]] = {True: collections.deque(),
                                                               False: collections.deque()}
        self.dropped = 0
        self.floods: list[Requester] = []
        """Requesters whose replies were dropped, in the order they first were (each reported once)."""

    def submit(self, who: Requester, msgs: list[Any], *, tag: Any = None, unique: bool = False) -> int:
        """Queue ``msgs`` for ``who``; how many were queued. With ``unique``, nothing is queued while a reply with
        the same ``tag`` still waits (a repeated PARAM_REQUEST_LIST, a retransmitted FTP request)."""
        flood = False
        with self._lock:
            if who not in self._queues and len(self._queues) >= self.max_requesters and not who[2]:
                who = OVERFLOW
            queue = self._queues.get(who)
            if queue is None:
                queue = self._queues[who] = _Queue(tokens=self._burst(), at=self._clock())
                self._turn[who[2]].append(who)
            if unique and tag is not None and any(t == tag for t, _ in queue.items):
                return 0
            room = max(0, self.per_requester - len(queue.items))
            for msg in msgs[:room]:
                queue.items.append((tag, msg))
            lost = len(msgs) - min(room, len(msgs))
            if lost:
                queue.dropped += lost
                self.dropped += lost
                if who not in self.floods:
                    self.floods.append(who)
                    flood = True
        if flood and self._on_flood is not None:
            self._on_flood(who)
        return min(room, len(msgs))

    def next(self) -> Any | None:
        """The next reply to send (signed requesters first, each in turn), or None."""
        with self._lock:
            now = self._clock()
            for signed in (True, False):
                turn = self._turn[signed]
                for _ in range(len(turn)):
                    who = turn[0]
                    turn.rotate(-1)
                    queue = self._queues[who]
                    if not queue.items:
                        continue
                    _, msg = queue.items[0]
                    if not signed and not self._take(queue, wire_estimate(msg), now):
                        continue
                    queue.items.popleft()
                    queue.sent += 1
                    return msg
            if self.work_conserving:
                for who in self._turn[False]:
                    queue = self._queues[who]
                    if queue.items:
                        queue.sent += 1
                        return queue.items.popleft()[1]
            return None

    def pending(self) -> int:
        with self._lock:
            return sum(len(q.items) for q in self._queues.values())

    def stats(self) -> dict[str, object]:
        with self._lock:
            return {"pending": sum(len(q.items) for q in self._queues.values()), "dropped": self.dropped,
                    "flooding": [f"{s}/{c}{'' if signed else ' unsigned'}" for s, c, signed in self.floods]}

    def _burst(self) -> float:
        return max(300.0, self._rate() * self.unsigned_share)

    def _take(self, queue: _Queue, cost: int, now: float) -> bool:
        """An unsigned requester's bucket: ``unsigned_share`` of the link's rate, a second's worth at most."""
        queue.tokens = min(self._burst(), queue.tokens + (now - queue.at) * self._rate() * self.unsigned_share)
        queue.at = now
        if queue.tokens < cost:
            return False
        queue.tokens -= cost
        return True
