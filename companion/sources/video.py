"""A video file through OpenCV's FFmpeg backend (H.264, HEVC, MJPEG, ...), subsampled to the target rate.

A corrupt or truncated file yields what can be decoded; frames the container announces but that never decode
are counted in ``lost``. Only a file from which nothing at all decodes is an error, and so is an MP4 cut short
before its index (``moov``) was written: nothing can open it, and the error says so (``mp4_index``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2

from companion.errors import UsageError
from companion.sources.base import FrameSource
from companion.sources.ffmpeg_log import opening
from companion.sources.frame import Frame
from companion.sources.mp4_index import missing_mp4_index, no_index_message
from companion.sources.subsample import Pacer, RateSubsampler

log = logging.getLogger(__name__)

DEFAULT_SOURCE_FPS = 30.0
"""Assumed when the container does not state a usable frame rate."""
MAX_GRAB_RETRIES = 8
"""Failed grabs tolerated in a row before the file is taken to have ended (skips a damaged packet or two)."""


class VideoSource(FrameSource):
    """Frames of one video file at ``fps``, each with its 0-based source index and source time."""

    def __init__(self, path: str | Path, *, fps: float = 5.0, realtime: bool = False, loop: bool = False) -> None:
        self.path = Path(path)
        self.name = str(self.path)
        self.fps = float(fps)
        self.realtime = realtime
        self.loop = loop
        self.lost = 0
        self.decoded = 0
        self._cap: cv2.VideoCapture | None = None
        self._cap_lock = threading.Lock()
        """Held around every call into the decoder: ``close`` from another thread (the live companion stopping)
        must not release the capture while the reading thread is inside grab() (FFmpeg hangs or crashes)."""
        self._closed = False
        self.source_fps, self.frame_count = self._probe()

    def _open(self) -> cv2.VideoCapture:
        with opening():  # a file that is not a video: our error below is the only line on stderr
            cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            if missing_mp4_index(self.path):
                raise UsageError(no_index_message(self.path))
            raise UsageError(f"{self.path}: cannot be opened as a video (unknown format, or damaged beyond reading)")
        return cap

    def _probe(self) -> tuple[float, int]:
        if not self.path.is_file():
            raise UsageError(f"{self.path}: no such video file")
        cap = self._open()
        fps = cap.get(cv2.CAP_PROP_FPS)
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        cap.release()
        if not fps or not math.isfinite(fps) or fps <= 0 or fps > 1000:
            log.warning("%s: no usable frame rate in the container, assuming %g fps", self.path, DEFAULT_SOURCE_FPS)
            fps = DEFAULT_SOURCE_FPS
        count = int(count) if count and math.isfinite(count) and count > 0 else 0
        return float(fps), count

    def __iter__(self) -> Iterator[Frame]:
        pacer = Pacer(self.realtime)
        offset_index, offset_time = 0, 0.0
        while True:
            read = yield from self._one_pass(pacer, offset_index, offset_time)
            if self._closed:
                return
            if self.decoded == 0:
                raise UsageError(f"{self.path}: no frame could be decoded (corrupt or truncated video)")
            if not self.loop or read == 0:
                return
            offset_index += read
            offset_time += read / self.source_fps

    def _one_pass(self, pacer: Pacer, offset_index: int, offset_time: float) -> Iterator[Frame]:
        """Decodes the file once; returns how many frame positions it went through."""
        with self._cap_lock:
            if self._closed:
                return 0
            cap = self._cap = self._open()
        sub = RateSubsampler(self.fps)
        index, failures = 0, 0
        try:
            while True:
                with self._cap_lock:
                    if self._closed:
                        break
                    grabbed = cap.grab()
                    ok, image = cap.retrieve() if grabbed and sub.keep(index / self.source_fps) else (None, None)
                if not grabbed:
                    failures += 1
                    if failures > MAX_GRAB_RETRIES or (self.frame_count and index >= self.frame_count):
                        break
                    continue
                failures = 0
                time_s = index / self.source_fps
                if ok is not None:  # kept by the subsampler: retrieved
                    if not ok or image is None:
                        self.lost += 1
                    else:
                        self.decoded += 1
                        pacer.wait(offset_time + time_s)
                        yield Frame(image, offset_index + index, offset_time + time_s, time.time())
                else:
                    self.decoded += 1
                index += 1
        finally:
            with self._cap_lock:
                cap.release()
                self._cap = None
        missing = 0 if self._closed else max(0, self.frame_count - index)
        if missing:
            self.lost += missing
            log.warning("%s: %d of %d frames could not be decoded", self.path, missing, self.frame_count)
        return index

    def close(self) -> None:
        """Stop reading (safe from another thread: waits for a grab in progress, then releases the file)."""
        with self._cap_lock:
            self._closed = True
            if self._cap is not None:
                self._cap.release()
                self._cap = None
