"""Decode ahead of inference: a thread reads the source (and downscales each frame) into a bounded queue.

OpenCV decodes and resizes with the GIL released, so on a small machine this overlaps decoding with the
encoder's matrix work instead of adding to it. The consumer takes batches: it waits for one frame, then takes
whatever else is already queued, up to the batch size, so latency stays bounded and throughput grows under load.
An error in the source (e.g. a video with nothing decodable) is raised in the consumer.

With a frame gate (``companion.vision.gate.FrameGate``, the pipeline's own), the decode thread also decides which
frames are worth encoding: a skipped frame comes out as ``(frame, None)`` and does not count toward the batch
size, so the encoder still gets full batches when the gate skips most frames (batches of mostly skipped frames
would leave it running at batch 1-2, far below its batched rate). The consumer hands such batches to
``Pipeline.process(..., gated=True)``. Nothing downstream reads a skipped frame's pixels, so it travels without them
(an empty image): at 1080p each held frame is 6 MB.

The read-ahead is bounded twice: ``depth`` items, and ``max_bytes`` of pixels (the full frames the consumer has
not taken yet). At 1080p, 32 frames ahead held 200 MB, a fifth of the companion's memory budget, to keep a
two-core encoder busy that needs one batch ahead.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np

from companion.sources.base import FrameSource
from companion.sources.frame import Frame

_END = object()
_NO_PIXELS = np.zeros((0, 0, 3), np.uint8)
"""What a skipped frame carries in place of its image."""

MAX_BYTES = 64 << 20
"""Default bound on the pixels decoded ahead (ten 1080p frames, ninety at 640x360, where ``depth`` binds first)."""


class FrameFeed:
    """Iterate ``batches(n)`` to get lists of (frame, prepared image) from ``source`` decoded in the background."""

    def __init__(self, source: FrameSource, prepare: Callable[[np.ndarray], np.ndarray] | None = None, *,
                 depth: int = 32, max_bytes: int = MAX_BYTES, limit: int | None = None, gate=None) -> None:
        self.source = source
        self.prepare = prepare
        self.gate = gate
        """Only the decode thread calls it while the feed runs."""
        self.limit = limit
        self.decode_seconds = 0.0
        self.decoded = 0
        self.max_bytes = max_bytes
        self.most_bytes_ahead = 0
        """The most pixel bytes the read-ahead held at once."""
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._bytes_ahead = 0
        self._room = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="frame-feed", daemon=True)
        self._started = False

    def _reserve(self, nbytes: int) -> bool:
        """Wait until ``nbytes`` more fit in ``max_bytes`` (one frame always fits when none is held)."""
        with self._room:
            while self._bytes_ahead and self._bytes_ahead + nbytes > self.max_bytes:
                if self._stop.is_set():
                    return False
                self._room.wait(0.1)
            self._bytes_ahead += nbytes
            self.most_bytes_ahead = max(self.most_bytes_ahead, self._bytes_ahead)
            return True

    def _taken(self, item: object) -> None:
        if isinstance(item, tuple):
            with self._room:
                self._bytes_ahead -= item[0].image.nbytes
                self._room.notify()

    def _put(self, item: object) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            start = time.perf_counter()
            for frame in self.source:
                small = self.prepare(frame.image) if self.prepare is not None else frame.image
                if self.gate is not None and not self.gate.admit(small, frame.time_s):
                    small = None
                    frame = dataclasses.replace(frame, image=_NO_PIXELS)
                self.decode_seconds += time.perf_counter() - start
                self.decoded += 1
                if not self._reserve(frame.image.nbytes) or not self._put((frame, small)):
                    break
                if self.limit is not None and self.decoded >= self.limit:
                    break
                start = time.perf_counter()
            self._put(_END)
        except BaseException as err:  # handed to the consumer, which raises it
            self._put(err)

    @property
    def gated(self) -> bool:
        return self.gate is not None

    def batches(self, size: int) -> Iterator[list[tuple[Frame, np.ndarray | None]]]:
        """Lists of (frame, prepared image), at most ``size`` of them to encode (gated-out ones ride along)."""
        if not self._started:
            self._thread.start()
            self._started = True
        done = False
        while not done:
            item = self._queue.get()
            self._taken(item)
            batch: list[tuple[Frame, np.ndarray | None]] = []
            to_encode = 0
            while True:
                if item is _END:
                    done = True
                    break
                if isinstance(item, BaseException):
                    raise item
                batch.append(item)
                to_encode += item[1] is not None
                if to_encode >= size or len(batch) >= size * 16:  # bounded even when the gate skips everything
                    break
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                self._taken(item)
            if batch:
                yield batch

    def close(self) -> None:
        """Stop the decode thread and release the source."""
        self._stop.set()
        if self._started:
            self._thread.join(timeout=5.0)
        self.source.close()

    def __enter__(self) -> FrameFeed:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
