"""The capture and inference loops of the live companion, each on its own thread.

Capture reads the (retrying) source as fast as it delivers and puts frames on a bounded drop-oldest queue;
inference takes whatever is waiting (up to the encoder batch), tags each frame with the vehicle's pose at its
capture time, runs the pipeline, and hands the summary events to the store and the surface link. Neither waits
for the other: a slow encoder costs dropped frames (counted), never a stalled camera or link.

The frame gate and the encoder's downscale run on the capture thread (``FrameAdmission``), as the offline decode
thread does (``companion.sources.frame_feed``): a frame the gate skips goes on as a light item without pixels, and
only the frames to encode fill the queue's few places. With both on the inference thread, that thread fell behind
the camera during each batch the encoder ran, and at 1080p60 6.8% of the frames were dropped at the input although
the gate let through far fewer frames than the encoder could take (``merlion bench soak --clip 1920x1080``).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.live.health import Health
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.sources.retrying import RetryingSource
from companion.vision.gate import FrameGate

log = logging.getLogger(__name__)

NO_PIXELS = np.zeros((0, 0, 3), np.uint8)
"""What a frame the gate skipped carries in place of its image: nothing downstream reads its pixels."""


@dataclass(frozen=True)
class Admitted:
    """A captured frame as the inference thread gets it, gated and downscaled on the capture thread."""

    frame: Frame
    prepared: np.ndarray | None
    """The encoder's copy; None: the frame gate skipped the frame, which then carries no pixels."""


def is_skipped(item: Admitted) -> bool:
    """A light item of the capture queue (``DropOldestQueue``'s ``light``)."""
    return item.prepared is None


def halved(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Halve ``image`` (area averaging by exactly 2, OpenCV's fast path) while the half still covers ``size``
    (w, h). At 1080p two halvings take ~1 ms where one area resize to the encoder's 398x224 took 16-30 ms on the
    shared 2-core machine: on the capture thread, at 60 frames/s, that was more than the thread had."""
    tw, th = size
    h, w = image.shape[:2]
    while w % 2 == 0 and h % 2 == 0 and w // 2 >= tw and h // 2 >= th:
        image = cv2.resize(image, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        h, w = image.shape[:2]
    return image


class FrameAdmission:
    """The frame gate in force and the encoder's downscale, for the capture thread.

    The gate looks at the encoder's copy, as the offline decode thread's does (``FrameFeed``), which is made from
    the frame halved while it covers the encoder's input (``halved``: the copy differs from a direct resize by
    ~1.6 grey levels on average). ``gate`` is called for the gate object each time (the selective stage's or the
    pipeline's, whichever is in force); the surface tunes its attributes from the keeper thread between two
    calls, which ``FrameGate.admit`` reads once per frame, so no lock is held against the encoder's batches."""

    def __init__(self, prepare: Callable[[np.ndarray], np.ndarray], gate: Callable[[], FrameGate],
                 size: tuple[int, int] = (0, 0)) -> None:
        self.prepare = prepare
        self.gate = gate
        self.size = size
        """The encoder's input (w, h); (0, 0): no halving first."""
        self.seconds = 0.0
        self.frames = 0

    def __call__(self, frame: Frame) -> Admitted:
        start = time.perf_counter()
        small = self.prepare(halved(frame.image, self.size) if any(self.size) else frame.image)
        kept = self.gate().admit(small, frame.time_s)
        item = Admitted(frame, small) if kept else Admitted(dataclasses.replace(frame, image=NO_PIXELS), None)
        self.seconds += time.perf_counter() - start
        self.frames += 1
        return item


@dataclass
class LiveCounters:
    """What the companion did; read by status, the demo report and the soak bench."""

    frames_seen: int = 0
    frames_scored: int = 0
    """Frames the encoder scored (the frame gate let them through)."""
    frames_skipped: int = 0
    """Frames the frame gate skipped as near-duplicates of the last encoded one (seen, never scored)."""
    frames_passed: int = 0
    frames_enhanced: int = 0
    summary_added: int = 0
    summary_removed: int = 0
    last_score: float | None = None
    inference_errors: int = 0
    recent: deque = field(default_factory=lambda: deque(maxlen=64))
    """Monotonic times of recently scored frames, for the frames/s figure."""
    recent_seen: deque = field(default_factory=lambda: deque(maxlen=64))
    """Monotonic times of recently seen frames (what the camera delivered), for the frames/s seen."""

    def fps(self, now: float | None = None) -> float:
        """Frames scored per second (the encoder's rate, after the frame gate and drops), not the camera's rate."""
        return _rate(self.recent, now)

    def seen_fps(self, now: float | None = None) -> float:
        """Frames seen per second: what the source delivers."""
        return _rate(self.recent_seen, now)

    def rates_text(self, now: float | None = None) -> str:
        """"scored 1.7/s of 5.0/s seen": the status figure, said so that nobody takes it for the camera's rate."""
        return f"scored {self.fps(now):.1f}/s of {self.seen_fps(now):.1f}/s seen"


def _rate(recent: deque, now: float | None) -> float:
    now = time.monotonic() if now is None else now
    # copy first: the inference thread appends while the status thread asks (iterating a deque that changes
    # raises RuntimeError); deque.copy() runs in C without letting another thread in
    times = [t for t in recent.copy() if now - t <= 10.0]
    if len(times) < 2:
        return 0.0
    span = max(times[-1] - times[0], 1e-6)
    return (len(times) - 1) / span


class CaptureLoop(threading.Thread):
    def __init__(self, source: RetryingSource, queue: DropOldestQueue, health: Health,
                 counters: LiveCounters, stop: threading.Event, admit: FrameAdmission | None = None) -> None:
        super().__init__(name="capture", daemon=True)
        self.source = source
        self.queue = queue
        self.health = health
        self.counters = counters
        self.stop_event = stop
        self.admit = admit
        """Gates and downscales each frame before it is queued (None: frames are queued as they come)."""
        self.ended = threading.Event()
        self.latest: Frame | None = None
        """The newest frame the camera gave: what the pilot's shutter keeps (``control.shutter``)."""

    @property
    def admit_clock(self) -> tuple[float, int] | None:
        """(seconds, frames) the admission took on this thread; None without one."""
        return None if self.admit is None else (self.admit.seconds, self.admit.frames)

    def run(self) -> None:
        self.health.register("capture")
        try:
            for frame in self.source:
                self.health.beat("capture")
                self.counters.frames_seen += 1
                self.counters.recent_seen.append(time.monotonic())
                self.latest = frame  # whole, before admission strips a skipped frame's pixels (the shutter's)
                self.queue.put(self.admit(frame) if self.admit is not None else frame)
                if self.stop_event.is_set():
                    break
        except Exception:  # noqa: BLE001 - the retrying source handles failures; this is a last guard
            log.exception("capture loop failed")
        finally:
            # an ended file or a stop is not a stuck stage
            self.health.forget("capture")
            self.ended.set()


class InferenceLoop(threading.Thread):
    """Drives the pipeline from the queue through the summary keeper (which stores and publishes the events)."""

    def __init__(self, pipeline, queue: DropOldestQueue, health: Health, counters: LiveCounters,
                 stop: threading.Event, *, batch: int, pose_at: Callable[[float], object] | None,
                 keeper: SummaryKeeper, selective=None) -> None:
        super().__init__(name="inference", daemon=True)
        self.pipeline = pipeline
        self.queue = queue
        self.health = health
        self.counters = counters
        self.stop_event = stop
        self.batch = batch
        self.pose_at = pose_at
        self.keeper = keeper
        """Runs each batch and stores its events as one change, so live tuning never lands mid-batch."""
        self.selective = selective
        """companion.live.enhance_worker.SelectiveStage when enhancement runs on its own worker; else None."""

    def run(self) -> None:
        self.health.register("inference")
        while not self.stop_event.is_set():
            items = self.queue.get_batch(self.batch, timeout=0.5)
            self.health.beat("inference")
            if not items:
                continue
            try:
                if isinstance(items[0], Admitted):  # gated and downscaled on the capture thread
                    self.step([a.frame for a in items], [a.prepared for a in items])
                else:
                    self.step(items)
            except Exception:  # noqa: BLE001 - one bad batch must not end the dive; it is logged and counted
                self.counters.inference_errors += 1
                log.exception("inference failed on %d frame(s); going on", len(items))
            self.health.beat("inference")
        self.health.forget("inference")

    def step(self, frames: list[Frame], prepared: list[np.ndarray | None] | None = None) -> None:
        """One batch; ``prepared``: the encoder's copies from the capture thread's ``FrameAdmission`` (None for
        a frame its gate skipped); without them the gate and the downscale run here."""
        poses = [self.pose_at(f.capture_time) for f in frames] if self.pose_at is not None else None
        if self.selective is not None and self.selective.on:
            self._score_for_enhancer(frames, poses, prepared)
            return
        if self.selective is not None:  # enhancer off: straight to the pipeline, behind the stage's frame gate
            ready = prepared if prepared is not None else self.selective.admit(frames)
            judge = self.selective.raw  # the raw frames' own dive (and its topics' marks) judges them, on or off
            outcome = self.keeper.change(
                lambda: self.pipeline.process(frames, ready, poses, gated=True, judge=judge), lambda o: o.events)
        elif prepared is not None:
            outcome = self.keeper.change(lambda: self.pipeline.process(frames, prepared, poses, gated=True),
                                         lambda o: o.events)
        else:
            outcome = self.keeper.change(lambda: self.pipeline.process(frames, poses=poses), lambda o: o.events)
        now = time.monotonic()
        c = self.counters
        for result in outcome.results:
            if not result.encoded:
                c.frames_skipped += 1
                continue
            c.frames_scored += 1
            c.frames_passed += int(result.passed)
            c.frames_enhanced += int(result.enhanced)
            c.last_score = result.score
            c.recent.append(now)
        for event in outcome.events:
            if event.kind == "added":
                c.summary_added += 1
            else:
                c.summary_removed += 1

    def _score_for_enhancer(self, frames: list[Frame], poses: list | None,
                            prepared: list[np.ndarray | None] | None) -> None:
        """MERLION-E: score here, enhance and sample on the enhancer's worker."""
        now = time.monotonic()
        c = self.counters
        for _frame, score, passed, encoded in self.selective.score(frames, poses, prepared):
            if not encoded:
                c.frames_skipped += 1
                continue
            c.frames_scored += 1
            c.frames_passed += int(passed)
            c.last_score = score
            c.recent.append(now)
