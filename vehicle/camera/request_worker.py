"""A thread that serves requests in arrival order, signed requesters first, so the MAVLink receive loop only
parses and hands off.

Anything slower than a parse (a full frame's JPEG encoding behind an FTP open, a parameter change that waits on
the pipeline lock and an fsync, an uploaded queries file being encoded) runs here and replies when done; the
receive loop, the heartbeat timer and the budget's sender keep running meanwhile. The queues are bounded: a flood
of requests drops the newest with a count rather than letting memory grow (a MAVLink client retransmits). Signed
and unsigned requests wait in queues of their own, and a signed one is served first: with a signing key, strangers
flooding unsigned requests (each within its per-requester rate, from many made-up ids) fill only their own queue
and cannot push the operator's requests out.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

from vehicle.link.warning_bucket import WarningBucket

log = logging.getLogger(__name__)

DROP_LOG_S = 10.0
"""At most one log line per this many seconds about dropped requests (a flood would otherwise fill the disk)."""


class RequestWorker:
    """One named thread running submitted jobs, signed ones first, each kind in order; ``submit`` never blocks."""

    def __init__(self, name: str, *, limit: int = 256) -> None:
        self.name = name
        self._limit = limit
        self._queues: dict[bool, deque[Callable[[], None]]] = {True: deque(), False: deque()}
        self._ready = threading.Condition()
        self._stopping = False
        self._thread: threading.Thread | None = None
        self.dropped = 0
        self.served = 0
        self.longest_s = 0.0
        """The longest single job so far (what the receive loop would have stalled for without this worker)."""
        self._drop_log = WarningBucket(burst=1, refill_s=DROP_LOG_S)

    def start(self) -> None:
        if self._thread is None:
            self._stopping = False
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Finish the job in hand, drop the rest and join."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        with self._ready:
            self._stopping = True
            for jobs in self._queues.values():
                jobs.clear()
            self._ready.notify()
        thread.join(timeout)

    def submit(self, job: Callable[[], None], *, signed: bool = False) -> bool:
        """Queue ``job`` (``signed``: from a requester whose message carried a valid signature); False (and
        counted) when its queue is full or the worker is stopped."""
        if self._thread is None:
            return False
        with self._ready:
            jobs = self._queues[bool(signed)]
            if len(jobs) >= self._limit:
                self.dropped += 1
                if self._drop_log.take():
                    log.warning("%s: request queue full, %d requests dropped so far", self.name, self.dropped)
                return False
            jobs.append(job)
            self._ready.notify()
        return True

    def _next(self) -> Callable[[], None] | None:
        with self._ready:
            while not self._stopping and not (self._queues[True] or self._queues[False]):
                self._ready.wait()
            if self._stopping:
                return None
            return (self._queues[True] or self._queues[False]).popleft()

    def _run(self) -> None:
        while (job := self._next()) is not None:
            start = time.perf_counter()
            try:
                job()
            except Exception:
                log.exception("%s: request failed", self.name)
            self.served += 1
            self.longest_s = max(self.longest_s, time.perf_counter() - start)
