"""The capture and inference loops of the live companion, each on its own thread.

Capture reads the (retrying) source as fast as it delivers and puts frames on a bounded drop-oldest queue;
inference takes whatever is waiting (up to the encoder batch), tags each frame with the vehicle's pose at its
capture time, runs the pipeline, and hands the summary events to the store and the surface link. Neither waits
for the other: a slow encoder costs dropped frames (counted), never a stalled camera or link.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from companion.live.health import Health
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.sources.retrying import RetryingSource

log = logging.getLogger(__name__)


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
    def __init__(self, source: RetryingSource, queue: DropOldestQueue[Frame], health: Health,
                 counters: LiveCounters, stop: threading.Event) -> None:
        super().__init__(name="capture", daemon=True)
        self.source = source
        self.queue = queue
        self.health = health
        self.counters = counters
        self.stop_event = stop
        self.ended = threading.Event()
        self.latest: Frame | None = None
        """The newest frame the camera gave: what the pilot's shutter keeps (``control.shutter``)."""

    def run(self) -> None:
        self.health.register("capture")
        try:
            for frame in self.source:
                self.health.beat("capture")
                self.counters.frames_seen += 1
                self.counters.recent_seen.append(time.monotonic())
                self.latest = frame
                self.queue.put(frame)
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

    def __init__(self, pipeline, queue: DropOldestQueue[Frame], health: Health, counters: LiveCounters,
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
            frames = self.queue.get_batch(self.batch, timeout=0.5)
            self.health.beat("inference")
            if not frames:
                continue
            try:
                self.step(frames)
            except Exception:  # noqa: BLE001 - one bad batch must not end the dive; it is logged and counted
                self.counters.inference_errors += 1
                log.exception("inference failed on %d frame(s); going on", len(frames))
            self.health.beat("inference")
        self.health.forget("inference")

    def step(self, frames: list[Frame]) -> None:
        poses = [self.pose_at(f.capture_time) for f in frames] if self.pose_at is not None else None
        if self.selective is not None and self.selective.on:
            self._score_for_enhancer(frames, poses)
            return
        if self.selective is not None:  # enhancer off: straight to the pipeline, behind the stage's frame gate
            prepared = self.selective.admit(frames)
            judge = self.selective.raw  # the raw frames' own dive (and its topics' marks) judges them, on or off
            outcome = self.keeper.change(
                lambda: self.pipeline.process(frames, prepared, poses, gated=True, judge=judge), lambda o: o.events)
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

    def _score_for_enhancer(self, frames: list[Frame], poses: list | None) -> None:
        """MERLION-E: score here, enhance and sample on the enhancer's worker."""
        now = time.monotonic()
        c = self.counters
        for _frame, score, passed, encoded in self.selective.score(frames, poses):
            if not encoded:
                c.frames_skipped += 1
                continue
            c.frames_scored += 1
            c.frames_passed += int(passed)
            c.last_score = score
            c.recent.append(now)
