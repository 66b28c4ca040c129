"""MERLION-E on the vehicle: selective enhancement on its own worker, off the inference thread.

The inference thread scores every frame (ss_t) and hands only the frames that pass tau_ss to this worker, through
a bounded drop-oldest queue (``enhance.queue``; drops are counted). The worker enhances each one, and the
pipeline, whose pre-sampler gate here is tau_ses, re-encodes the enhanced frame, scores it (ss_e), and offers
those above tau_ses to the sampler with the enhanced embedding: REFERENCE.md step 8, with a slow enhancer never
holding up the scoring of new frames. The copy is no frame of the dive: it is scored by the raw gate's
pre-samplers (the marks live there), from the row its frame had in the dive of raw frames (``Candidate.seen``).
The encoder is shared, so its calls are serialised by one lock; the enhancement itself runs outside it. With
several topics, the raw gate (``RawGate``) scores every topic on the one embedding; a candidate carries the topics
it passed for and may enter only their summaries.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

import numpy as np

from companion.live.health import Health
from companion.live.loops import LiveCounters
from companion.live.queues import DropOldestQueue
from companion.live.raw_gate import RawGate
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Captured, Frame
from companion.vision.dive_mean import DiveFrames
from companion.vision.gate import FrameGate

log = logging.getLogger(__name__)


@dataclass
class Candidate:
    """A frame that passed tau_ss, with what the sampler will need later."""

    frame: Frame
    score: float
    pose: object | None
    seen: DiveFrames
    """Its row as the raw gate's dive saw it (features, centred features, scene residual, embedding): its enhanced
    copy is judged by it (``Pipeline.process(seen=...)``), since the copy is not a frame of the raw dive."""
    topics: dict[str, float] = field(default_factory=dict)
    """The topics whose tau_ss it passed, with its ss_t for each: the only summaries it may enter after
    enhancement, and the raw score its enhanced copy is stored beside (``SummaryFrame.raw_score``)."""


class SelectiveStage:
    """The split pipeline: ``score`` on the inference thread, ``EnhanceWorker`` for the rest."""

    def __init__(self, pipeline, raw: RawGate, enhancer, *, queue_size: int, lock: threading.Lock,
                 gate: FrameGate | None = None) -> None:
        self.pipeline = pipeline
        """Built with enhancement off and its pre-sampler gate at tau_ses: it scores ss_e and samples."""
        self.raw = raw
        """The tau_ss gate on the frames as captured, one pre-sampler per topic."""
        self.enhancer = enhancer
        self.queue: DropOldestQueue[Candidate] = DropOldestQueue(queue_size)
        self.lock = lock
        self.enhanced = 0
        self.enhanced_passed = 0
        self.scored = 0
        """Frames the raw gate scored (under the lock, so it can be read beside the encoder's count)."""
        self.on = True
        """MERL_ENHANCE from the surface: off sends frames straight to the pipeline (gate back at tau_ss)."""
        self.gate = gate if gate is not None else FrameGate("none")
        """The frame gate (config ``gate:``, MERL_GATE) ahead of the raw scoring, enhancer on or off: the
        pipeline behind it samples sparse, already chosen candidates and gates nothing itself."""

    def sync_gates(self) -> None:
        """The pipeline's gate is tau_ses while the enhancer runs, else each topic's own tau_ss (the raw gate's),
        so switching MERL_ENHANCE off leaves every topic its threshold. Called inside a keeper change."""
        for topic in self.pipeline.topics:
            topic.presampler.tau_ss = self.pipeline.tau_ses if self.on else self.raw.tau_of(topic.name)

    def admit(self, frames: list[Frame]) -> list[np.ndarray | None]:
        """The encoder's copy of each frame the gate lets through, None for a frame it skips."""
        small = [self.pipeline.prepare(f.image) for f in frames]
        keep = self.gate.admit_batch(small, [f.time_s for f in frames])  # a gate that is off admits every frame
        return [s if k else None for s, k in zip(small, keep, strict=True)]

    def score(self, frames: list[Frame], poses: list | None,
              prepared: list[np.ndarray | None] | None = None) -> list[tuple[Frame, float, bool, bool]]:
        """(frame, best ss_t over the topics, passed, encoded) per frame: the gate goes first, then one encoder
        pass for every topic; a frame above any topic's tau_ss is queued for the enhancer (the oldest waiting one
        may go). A frame the gate skips is seen, never scored (NaN) and never a candidate. ``prepared``: the
        capture thread gated and downscaled them already (``companion.live.loops.FrameAdmission``)."""
        if prepared is None:
            prepared = self.admit(frames)
        go = [i for i, p in enumerate(prepared) if p is not None]
        out = [(frame, float("nan"), False, False) for frame in frames]
        if not go:
            return out
        with self.lock:
            emb = self.pipeline.encoder.encode_images([prepared[i] for i in go])
            scores, passed, seen = self.raw.score(emb)
            self.scored += len(go)
        for row, i in enumerate(go):
            frame = frames[i]
            if passed[row]:
                self.queue.put(Candidate(frame, float(scores[row]), poses[i] if poses is not None else None,
                                         seen.rows([row]), passed[row]))
            out[i] = (frame, float(scores[row]), bool(passed[row]), True)
        return out


class EnhanceWorker(threading.Thread):
    def __init__(self, stage: SelectiveStage, health: Health, counters: LiveCounters, stop: threading.Event, *,
                 batch: int, keeper: SummaryKeeper) -> None:
        super().__init__(name="enhance", daemon=True)
        self.stage = stage
        self.health = health
        self.counters = counters
        self.stop_event = stop
        self.batch = batch
        self.keeper = keeper

    def run(self) -> None:
        self.health.register("enhance")
        while not self.stop_event.is_set():
            items = self.stage.queue.get_batch(self.batch, timeout=0.5)
            self.health.beat("enhance")
            if not items:
                continue
            try:
                self.step(items)
            except Exception:  # noqa: BLE001 - a failed enhancement costs those frames, not the dive
                self.counters.inference_errors += 1
                log.exception("enhancement failed on %d frame(s); going on", len(items))
            self.health.beat("enhance")
        self.health.forget("enhance")

    def step(self, items: list[Candidate]) -> None:
        stage = self.stage
        frames: list[Frame] = []
        for item in items:
            enhanced = stage.enhancer.enhance(item.frame.image)
            frames.append(Frame(enhanced, item.frame.index, item.frame.time_s, item.frame.capture_time,
                                captured=Captured(item.frame.image, dict(item.topics))))
            self.health.beat("enhance")
        poses = [item.pose for item in items]
        only = [item.topics for item in items]
        seen = DiveFrames.stack([item.seen for item in items])

        def sample():  # the frames as captured go to the store beside the enhanced ones (Frame.captured)
            return stage.pipeline.process(frames, poses=poses, only=only, seen=seen, judge=stage.raw)

        outcome = self.keeper.change(sample, lambda o: o.events)
        stage.enhanced += len(items)
        self.counters.frames_enhanced += len(items)
        stage.enhanced_passed += sum(r.passed for r in outcome.results)
        for event in outcome.events:
            if event.kind == "added":
                self.counters.summary_added += 1
            else:
                self.counters.summary_removed += 1
