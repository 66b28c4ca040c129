"""Keep a source alive: a camera that fails or disappears is reopened with back-off and reported; files may loop.

The companion must outlive its camera (a loose USB cable, a camera manager restarting, an RTSP server gone for a
minute). The wrapper owns the retry policy so the sources themselves stay simple: they raise when they cannot
deliver, and here that becomes a log line, a counter, a wait that doubles up to a limit, and a fresh open.
A file or folder that ends is said once; it starts again with ``loop``, else the wrapper stops yielding and the
rest of the companion (the surface link) keeps serving.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator

from companion.errors import MerlionError
from companion.sources.base import FrameSource
from companion.sources.frame import Frame

log = logging.getLogger(__name__)


class RetryingSource(FrameSource):
    """Wraps a source factory; ``state`` is running | retrying | ended | closed, for status and health."""

    def __init__(self, open_source: Callable[[], FrameSource], *, name: str, live: bool, loop: bool = False,
                 initial_s: float = 1.0, max_s: float = 30.0,
                 on_state: Callable[[str, str], None] | None = None,
                 beat: Callable[[], None] | None = None) -> None:
        self.name = name
        self.live = live
        self.loop = loop
        self.initial_s = initial_s
        self.max_s = max_s
        self.lost = 0
        self.failures = 0
        self.opens = 0
        self.ended = 0
        self.state = "starting"
        self.last_error = ""
        self._open = open_source
        self._on_state = on_state
        self._beat = beat
        """Called at least every second while waiting to retry: waiting for a camera is not being stuck."""
        self._current: FrameSource | None = None
        self._stop = threading.Event()
        self._index_offset = 0
        self._time_offset = 0.0

    def _set(self, state: str, detail: str = "") -> None:
        if state != self.state:
            self.state = state
            if self._on_state is not None:
                self._on_state(state, detail)

    def __iter__(self) -> Iterator[Frame]:
        delay = self.initial_s
        while not self._stop.is_set():
            try:
                source = self._open()
            except Exception as err:  # noqa: BLE001 - every failure is retried, never fatal
                self._failed(err, delay)
                if self._wait(delay):
                    break
                delay = min(delay * 2, self.max_s)
                continue
            self._current = source
            self.opens += 1
            last_index, last_time, produced = -1, 0.0, 0
            try:
                for frame in source:
                    if self._stop.is_set():
                        break
                    if produced == 0:
                        if self.state in ("retrying", "ended"):
                            log.warning("source %s: back after %d failure(s)", self.name, self.failures)
                        self._set("running", self.name)
                        delay = self.initial_s
                    produced += 1
                    last_index, last_time = frame.index, frame.time_s
                    # indices and times keep growing across reopenings and loops (the store keys on them)
                    yield Frame(frame.image, frame.index + self._index_offset, frame.time_s + self._time_offset,
                                frame.capture_time)
                self.lost += getattr(source, "lost", 0)
            except Exception as err:  # noqa: BLE001 - a source that breaks mid-stream is retried
                self.lost += getattr(source, "lost", 0)
                self._close_current()
                self._index_offset += last_index + 1
                self._time_offset += last_time
                self._failed(err, delay)
                if self._wait(delay):
                    break
                delay = min(delay * 2, self.max_s)
                continue
            self._close_current()
            self._index_offset += last_index + 1
            self._time_offset += last_time
            if self._stop.is_set():
                break
            if self.live:
                self._failed(MerlionError("stream ended"), delay)
                if self._wait(delay):
                    break
                delay = min(delay * 2, self.max_s)
                continue
            self.ended += 1
            if self.loop and produced:
                log.info("source %s: ended; starting again (loop)", self.name)
                continue
            log.warning("source %s: ended after %d frames; the companion keeps serving until stopped",
                        self.name, last_index + 1)
            self._set("ended", "end of source")
            return
        self._set("closed")

    def _wait(self, delay: float) -> bool:
        """Back-off that close() interrupts; True when closed."""
        end = time.monotonic() + delay
        while True:
            if self._beat is not None:
                self._beat()
            left = end - time.monotonic()
            if left <= 0:
                return self._stop.is_set()
            if self._stop.wait(min(1.0, left)):
                return True

    def _failed(self, err: BaseException, delay: float) -> None:
        self.failures += 1
        # the source's own errors already start with "source NAME: "; the log line below names it once
        self.last_error = (str(err) or type(err).__name__).removeprefix(f"source {self.name}: ")
        log.warning("source %s: %s; retrying in %.1f s", self.name, self.last_error, delay)
        self._set("retrying", self.last_error)

    def _close_current(self) -> None:
        current, self._current = self._current, None
        if current is not None:
            try:
                current.close()
            except Exception:  # noqa: BLE001 - a broken device may fail to close; nothing more to do
                pass

    def close(self) -> None:
        self._stop.set()
        self._close_current()
