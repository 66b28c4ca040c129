"""The log's side of refused unsigned messages: the first in full, then a count per interval.

Each new source of a refused write got a WARNING line of its own; made-up system ids are free, so the issue 46 flood
(200 of them) wrote some 200 lines that buried the rest of the log. Now the first new source of a spell is logged
in full (what was refused, from whom), and the new sources after it are counted and said in at most one line per
``interval_s``, naming the last of them. Who was refused how often stays in ``LinkSigning.stats()``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

REFUSAL_LOG_INTERVAL_S = 10.0


class RefusalLog:
    """Log lines about new sources of refused messages, at most one per ``interval_s`` after the first; thread-safe
    (refusals come on the receive thread, ``flush`` on the link's timer thread)."""

    def __init__(self, name: str, logger: logging.Logger, *, interval_s: float = REFUSAL_LOG_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.name = name
        self.logger = logger
        self.interval_s = interval_s
        self.clock = clock
        self.withheld = 0
        """New sources counted instead of logged, over the whole run."""
        self._pending = 0
        self._last = ""
        self._quiet_until: float | None = None
        self._lock = threading.Lock()

    def refused(self, text: str) -> None:
        """A source's first refused message, as ``text`` ("unsigned FTP write from 57/190 ignored")."""
        with self._lock:
            now = self.clock()
            if self._quiet_until is None or (now >= self._quiet_until and not self._pending):
                self._quiet_until = now + self.interval_s
                self.logger.warning("%s: %s (further ones from it are only counted; more sources within %.0f s "
                                    "are counted in one line)", self.name, text, self.interval_s)
                return
            self._pending += 1
            self.withheld += 1
            self._last = text
        self.flush()

    def flush(self) -> None:
        """Say how many new sources were refused since the last line, once ``interval_s`` has passed since it."""
        with self._lock:
            now = self.clock()
            if not self._pending or self._quiet_until is None or now < self._quiet_until:
                return
            count, last, self._pending = self._pending, self._last, 0
            self._quiet_until = now + self.interval_s
        self.logger.warning("%s: refused messages from %d more source%s since the last such line, each only "
                            "counted (the last: %s)", self.name, count, "" if count == 1 else "s", last)
