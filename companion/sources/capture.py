"""A live OpenCV capture (camera or network stream) thinned to the target frame rate by wall-clock time.

Live sources cannot be subsampled by frame number (cameras skip and stutter), so a frame is kept when at least
1/fps seconds passed since the last kept one. A read that fails raises :class:`SourceLost`; the retrying wrapper
turns that into back-off and a reconnect, so the companion stays up.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator

import cv2

from companion.sources.base import FrameSource
from companion.sources.frame import Frame

log = logging.getLogger(__name__)


class SourceLost(Exception):
    """The camera or stream stopped delivering frames (unplugged, network gone); worth retrying."""


class CaptureSource(FrameSource):
    """Frames from an opened ``cv2.VideoCapture``, kept at most ``fps`` per second."""

    max_failed_reads = 25
    """Consecutive failed reads before the device counts as gone (a live camera hiccups now and then)."""

    def __init__(self, name: str, open_capture: Callable[[], cv2.VideoCapture], *, fps: float) -> None:
        self.name = name
        self.fps = float(fps)
        self.lost = 0
        self._open_capture = open_capture
        self._cap: cv2.VideoCapture | None = None
        self._closed = False
        self._iterating = False

    def open(self) -> cv2.VideoCapture:
        cap = self._open_capture()
        if cap is None or not cap.isOpened():
            if cap is not None:
                cap.release()
            raise SourceLost(f"{self.name}: cannot open")
        self._cap = cap
        return cap

    def __iter__(self) -> Iterator[Frame]:
        cap = self._cap or self.open()
        self._iterating = True
        try:
            yield from self._frames(cap)
        finally:
            # released by the thread that reads: releasing under a running read() crashes FFmpeg
            self._iterating = False
            self._release()

    def _frames(self, cap: cv2.VideoCapture) -> Iterator[Frame]:
        period = 1.0 / self.fps
        start = time.monotonic()
        next_due = start
        index = 0
        failed = 0
        while not self._closed:
            ok, image = cap.read()
            now = time.monotonic()
            if self._closed:
                return
            if not ok or image is None:
                failed += 1
                if failed >= self.max_failed_reads:
                    raise SourceLost(f"{self.name}: no frames ({failed} failed reads)")
                time.sleep(min(period, 0.05))
                continue
            failed = 0
            index += 1
            if now < next_due:
                continue
            next_due = max(next_due + period, now - period)
            yield Frame(image=image, index=index - 1, time_s=now - start, capture_time=time.time())

    def _release(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def close(self) -> None:
        """Safe from any thread: a reading thread releases the device itself when it sees the flag."""
        self._closed = True
        if not self._iterating:
            self._release()
