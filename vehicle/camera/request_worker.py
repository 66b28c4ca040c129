"""A thread that serves requests in arrival order, so the MAVLink receive loop only parses and hands off.

Anything slower than a parse (a full frame's JPEG encoding behind an FTP open, a parameter change that waits on
the pipeline lock and an fsync, an uploaded queries file being encoded) runs here and replies when done; the
receive loop, the heartbeat timer and the budget's sender keep running meanwhile. The queue is bounded: a flood
of requests drops the newest with a count rather than letting memory grow (a MAVLink client retransmits).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)


class RequestWorker:
    """One named thread running submitted jobs in order; ``submit`` never blocks."""

    def __init__(self, name: str, *, limit: int = 256) -> None:
        self.name = name
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=limit)
        self._thread: threading.Thread | None = None
        self.dropped = 0
        self.served = 0
        self.longest_s = 0.0
        """The longest single job so far (what the receive loop would have stalled for without this worker)."""

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Finish the job in hand, drop the rest and join."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        while True:
            try:
                self._jobs.get_nowait()
            except queue.Empty:
                break
        self._jobs.put(None)
        thread.join(timeout)

    def submit(self, job: Callable[[], None]) -> bool:
        """Queue ``job``; False (and counted) when the queue is full or the worker is stopped."""
        if self._thread is None:
            return False
        try:
            self._jobs.put_nowait(job)
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 100 == 0:
                log.warning("%s: request queue full, %d requests dropped", self.name, self.dropped)
            return False
        return True

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            start = time.perf_counter()
            try:
                job()
            except Exception:
                log.exception("%s: request failed", self.name)
            self.served += 1
            self.longest_s = max(self.longest_s, time.perf_counter() - start)
