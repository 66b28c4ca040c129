"""The vision core, one batch at a time: encode, score, pre-sample, enhance selectively, sample.

Both the offline tools (``merlion summarize``, ``merlion bench pipeline``) and the live companion drive the same
``Pipeline.process``: hand it a batch of frames (and, if the caller already downscaled them, the small copies),
get back one result per frame and the summary events it caused. It keeps no thread of its own, so the live loop
runs it from its inference thread; ``companion.sources.frame_feed`` supplies batches from a decode thread offline.

Enhancement (REFERENCE.md step 8, MERLION-E), by ``enhance.mode``:

- ``none``: frames are scored and sampled as captured;
- ``selective``: only frames with ``ss_t > tau_ss`` are enhanced (at full resolution), re-encoded and scored
  again; such a frame goes on only if ``ss_e > tau_ses``, and the sampler gets the enhanced embedding;
- ``always``: every frame is enhanced before it is encoded, and ``ss_t`` of the enhanced frame is tested against
  ``tau_ss`` (the "enhance everything" baseline that selective enhancement is measured against).

Several named topics (``companion.vision.topics``, config ``queries.topics``) share one encoder pass: each
scores the same embeddings with its own queries and keeps its own summary; a frame may enter several of them
(each entry is its own summary frame with its own image index). They share the dive too: the pipeline owns the
dive's running mean (``dive``, ``companion.vision.dive_mean``), feeds it each encoded frame once and every topic's
pre-sampler reads it (the operator's marks are centred by it).

While a topic's summary is empty and nothing passes its gate, its best frames so far stand in, marked
``below_threshold`` (``companion.vision.below_threshold``): after ``quiet_s`` seconds of footage, or at ``finish``.

Before all of that, the frame gate (``companion.vision.gate``, config ``gate:``) lets through only the frames
that differ from the last encoded one or come after a gap (in seconds, or in a share of the frames seen so far);
a skipped frame gets a result with ``encoded=False`` (counted as seen, never scored, never offered to the
sampler).
"""

from __future__ import annotations

import time
from collections.abc import Collection, Iterable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.config import Config, as_fraction
from companion.errors import UsageError
from companion.sources.frame import Frame
from companion.vision import distances as dist
from companion.vision.dive_mean import DiveFrames, DiveWindow
from companion.vision.encoders.base import Encoder
from companion.vision.enhancers.base import Enhancer
from companion.vision.enhancers.factory import make_enhancer
from companion.vision.events import SummaryEvent, SummaryFrame
from companion.vision.frame_result import BatchOutcome, FrameResult, raw_behind
from companion.vision.gate import FrameGate
from companion.vision.image_indices import ImageIndices
from companion.vision.pilot_capture import refile_pilot_frames, take_pilot_frame
from companion.vision.presampler import PreSampler
from companion.vision.sampler import InformativeSampler
from companion.vision.stand_in_stage import all_keys, finish_events, stand_in_events
from companion.vision.topics import (
    OuterDive,
    Topic,
    TopicSpec,
    by_topic_name,
    check_names,
    follow,
    score_matrix,
)
from vehicle.autopilot.pose import Pose

ENHANCE_MODES = ("none", "always", "selective")


@dataclass
class StageClock:
    """Seconds spent and items handled per stage, for status and benchmarks."""

    seconds: dict[str, float] = field(default_factory=dict)
    items: dict[str, int] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str, items: int = 1):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            self.items[name] = self.items.get(name, 0) + items

    def ms_per_item(self) -> dict[str, float]:
        # copies first: the inference thread may add a stage while the status thread asks (dict.copy runs in C,
        # without letting another thread in; iterating the live dict could raise "changed size during iteration")
        seconds, items = self.seconds.copy(), self.items.copy()
        return {k: 1000.0 * v / max(1, items.get(k, 0)) for k, v in seconds.items()}


def downscale_for(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Shrink (never enlarge) keeping the aspect ratio so the frame still covers ``size`` (w, h).

    Encoders resize and centre-crop to their input themselves; handing them a frame just above that size makes
    their work cheap without changing what they crop.
    """
    h, w = image.shape[:2]
    tw, th = size
    scale = max(tw / w, th / h)
    if scale >= 1.0:
        return image
    nw, nh = max(tw, round(w * scale)), max(th, round(h * scale))
    # area averaging avoids aliasing on strong reductions; for mild ones bilinear is as good and ~6x cheaper
    interp = cv2.INTER_AREA if scale < 0.5 else cv2.INTER_LINEAR
    return cv2.resize(image, (nw, nh), interpolation=interp)


class Pipeline:
    """Encoder + pre-sampler + optional enhancer + informative sampler per topic, with running image indices."""

    def __init__(self, encoder: Encoder, topics: Sequence[Topic], *,
                 enhancer: Enhancer | None = None, enhance_mode: str = "none", tau_ses: float = 0.7,
                 first_image_index: int = 0, gate: FrameGate | None = None, default_tau_ss: float | None = None,
                 default_topic: str | None = None, quiet_s: float = 60.0) -> None:
        check_names([t.name for t in topics])
        if enhance_mode not in ENHANCE_MODES:
            raise UsageError(f"enhance.mode: {enhance_mode!r} is not one of {', '.join(ENHANCE_MODES)}")
        if enhance_mode != "none" and enhancer is None:
            raise UsageError(f"enhance.mode {enhance_mode}: no enhancer given")
        self.encoder = encoder
        self.dive = DiveWindow()
        """The dive so far, one for every topic: fed once per encoded frame (``_process_encoded``)."""
        for topic in topics:
            topic.presampler.dive = self.dive
        self.topics: list[Topic] = list(topics)
        """The topics followed, the default (first) one first."""
        duplicate = getattr(encoder, "duplicate_cosine", None)
        if duplicate is not None:  # the encoder knows how close its features come for the same picture
            for topic in topics:
                topic.sampler.duplicate_cosine = duplicate
        self._sampler_args = (topics[0].sampler.k, topics[0].sampler.distance, topics[0].sampler.threshold,
                              topics[0].sampler.duplicate_cosine)
        self.default_tau_ss = topics[0].presampler.tau_ss if default_tau_ss is None else default_tau_ss
        """tau_ss of a topic without its own (``queries.tau_ss``, then MERL_TAU_SS): a topic added live takes it."""
        self.default_topic = topics[0].name if default_topic is None else default_topic
        """``queries.name``: the topic of frames stored before topics existed (they carry none)."""
        self.enhancer = enhancer
        self.enhance_mode = enhance_mode
        self.tau_ses = tau_ses
        self.indices = ImageIndices(first_image_index)
        self.encode_size = encoder.input_size
        self.clock = StageClock()
        self.gate = gate if gate is not None else FrameGate("none")
        self.quiet_s = float(quiet_s)
        """Footage seconds with nothing passing after which an empty topic shows its best frames (stand-ins)."""
        self.counts = {"frames": 0, "encoded": 0, "skipped": 0, "passed": 0, "enhanced": 0, "enhanced_passed": 0,
                       "offered": 0, "added": 0, "duplicates": 0}

    @classmethod
    def from_config(cls, cfg: Config, encoder: Encoder, *, first_image_index: int = 0) -> Pipeline:
        """Everything but the encoder from the configuration; the enhancer is imported only when it is used."""
        s = cfg.sampler
        topics = [Topic(t.name, PreSampler(encoder, t.positive, t.negatives,  # the pipeline gives them its dive
                                           cfg.queries.tau_ss if t.tau_ss is None else t.tau_ss),
                        InformativeSampler(s.k, s.distance, s.threshold))
                  for t in cfg.queries.topic_list()]
        enhancer = None
        if cfg.enhance.mode != "none":
            enhancer = make_enhancer(cfg.enhance, device=cfg.encoder.device)
        gate = FrameGate(cfg.gate.mode, cfg.gate.threshold, cfg.gate.max_gap_s, cfg.gate.max_gap_share)
        return cls(encoder, topics, default_tau_ss=cfg.queries.tau_ss, default_topic=cfg.queries.name,
                   enhancer=enhancer, enhance_mode=cfg.enhance.mode,
                   tau_ses=cfg.enhance.tau_ses, first_image_index=first_image_index, gate=gate,
                   quiet_s=cfg.queries.below_threshold_after_s)

    # ----- topics -------------------------------------------------------------------------------------------

    @property
    def presampler(self) -> PreSampler:
        """The default (first) topic's pre-sampler: all there is with one topic."""
        return self.topics[0].presampler

    @presampler.setter
    def presampler(self, value: PreSampler) -> None:
        value.dive = self.dive
        self.topics[0].presampler = value

    @property
    def sampler(self) -> InformativeSampler:
        """The default (first) topic's sampler (K, distance and threshold are the same for every topic)."""
        return self.topics[0].sampler

    def topic(self, name: str) -> Topic:
        for topic in self.topics:
            if topic.name == name:
                return topic
        raise KeyError(name)

    def topic_of(self, image_index: int) -> Topic | None:
        """The topic whose summary holds that image, if any."""
        for topic in self.topics:
            if image_index in topic.held:
                return topic
        return None

    def untagged_topic(self) -> str:
        """Where a frame stored before topics existed (it names none) belongs: the default topic
        (``queries.name``) while it is followed, else the first topic."""
        names = [t.name for t in self.topics]
        return self.default_topic if self.default_topic in names else names[0]

    def set_topics(self, specs: Sequence[TopicSpec]) -> list[SummaryEvent]:
        """Follow these topics from now on: a kept name keeps its summary (its queries and threshold may change),
        a new name starts empty, and the frames of a topic no longer listed leave the summary (the events say so).
        """
        check_names([s.name for s in specs])
        old = {t.name: t for t in self.topics}
        topics = []
        for spec in specs:
            topic = old.pop(spec.name, None)
            if topic is None:
                topic = Topic(spec.name, follow(spec, None, self.encoder, self.default_tau_ss, self.dive),
                              InformativeSampler(*self._sampler_args))
            else:
                follow(spec, topic.presampler, self.encoder, self.default_tau_ss, self.dive)
            topics.append(topic)
        self.topics = topics
        refile_pilot_frames(list(old.values()), topics[0])  # the pilot's frames stay, under the first topic
        gone = [frame for topic in old.values() for frame in topic.summary]
        keys = self._all_keys()
        return [SummaryEvent("removed", frame, list(keys)) for frame in gone]

    # ----- live tuning --------------------------------------------------------------------------------------

    @property
    def tau_ss(self) -> float:
        return self.presampler.tau_ss

    @tau_ss.setter
    def tau_ss(self, value: float) -> None:
        """Every topic's threshold (live MERL_TAU_SS), and that of topics added later."""
        for topic in self.topics:
            topic.presampler.tau_ss = value
        self.default_tau_ss = self.topics[0].presampler.tau_ss  # as the pre-sampler read it (40 -> 0.4)

    @property
    def tau_ses(self) -> float:
        return self._tau_ses

    @tau_ses.setter
    def tau_ses(self, value: float) -> None:
        try:
            self._tau_ses = as_fraction(float(value))
        except ValueError as err:
            raise UsageError(f"tau_ses: {err}") from None

    def set_k(self, k: int) -> list[SummaryEvent]:
        """Change every topic's summary size now; a smaller K trims at once and reports the removals."""
        removed = [(topic, topic.sampler.set_k(k)) for topic in self.topics]
        self._sampler_args = (int(k), *self._sampler_args[1:])
        return self._removal_events(removed)

    # ----- the summary --------------------------------------------------------------------------------------

    @property
    def summary(self) -> list[SummaryFrame]:
        """The frames held now: topic by topic, each in the order they entered."""
        return [frame for topic in self.topics for frame in topic.summary]

    def _all_keys(self) -> list[int]:
        return all_keys(self.topics)

    def restore(self, frames: Iterable[SummaryFrame]) -> list[SummaryEvent]:
        """Resume with stored summary frames (their features and image indices); new indices continue above them.

        Each frame goes back to its topic's summary; a frame with no topic (stored by an earlier version) belongs
        to the default topic (``queries.name``; the first topic when that one is not followed), and a frame of a
        topic no longer followed is reported removed.
        """
        frames = sorted(frames, key=lambda f: f.image_index)
        by_topic, dropped = by_topic_name(frames, [t.name for t in self.topics], self.untagged_topic())
        removed = []
        pilots = [f for f in dropped if f.pilot]  # a pilot's frame never leaves: under the topic frames untagged go to
        dropped = [f for f in dropped if not f.pilot]
        for frame in pilots:
            frame.topic = self.untagged_topic()
            by_topic[frame.topic].append(frame)
        for topic in self.topics:
            mine = [f for f in by_topic[topic.name] if not f.below_threshold and not f.pilot]
            removed.append((topic, topic.sampler.restore((f.image_index, f.feature) for f in mine)))
            topic.held = {f.image_index: f for f in mine}
            topic.pilot = [f.image_index for f in by_topic[topic.name] if f.pilot]
            topic.held.update((f.image_index, f) for f in by_topic[topic.name] if f.pilot)
            for f in by_topic[topic.name]:
                if f.pilot:
                    continue
                if f.below_threshold and not mine:  # shown again until a frame passes
                    topic.below.showing(f)
                    topic.below.candidates.append(f)
                elif f.below_threshold:
                    dropped.append(f)
        if frames:
            self.indices.above(frames[-1].image_index)
        events = self._removal_events(removed)
        keys = self._all_keys()
        return events + [SummaryEvent("removed", frame, list(keys)) for frame in dropped]

    def capture(self, frame: Frame, pose: Pose | None) -> list[SummaryEvent]:
        """The pilot's shutter: keep ``frame`` as the pilot's own summary frame (``pilot_capture``)."""
        return take_pilot_frame(self.encoder, self.prepare(frame.image), self.topics, self.indices, frame, pose)

    def _removal_events(self, removed: Sequence[tuple[Topic, Sequence[int]]]) -> list[SummaryEvent]:
        gone = [topic.held.pop(key) for topic, keys in removed for key in keys]
        keys = self._all_keys()
        return [SummaryEvent("removed", frame, list(keys)) for frame in gone]

    # ----- one batch ----------------------------------------------------------------------------------------

    def prepare(self, image: np.ndarray) -> np.ndarray:
        """The copy the encoder sees; callers with a decode thread call this there, off the inference path."""
        return downscale_for(image, self.encode_size)

    def _encode(self, small: Sequence[np.ndarray], stage: str) -> np.ndarray:
        with self.clock.stage(stage, len(small)):
            return self.encoder.encode_images(list(small))

    def process(self, frames: Sequence[Frame], prepared: Sequence[np.ndarray | None] | None = None,
                poses: Sequence[Pose | None] | None = None, *, gated: bool = False,
                only: Sequence[Collection[str]] | None = None, seen: DiveFrames | None = None,
                judge: OuterDive | None = None) -> BatchOutcome:
        """Run one batch through every stage; returns per-frame results and the summary events, in frame order.
        The gate goes first; frames it skips get ``encoded=False`` results. ``gated``: the caller ran a frame gate
        (a decode thread's, the live selective stage's) and ``prepared[i] is None`` marks what it skipped.
        ``only``: per frame, the topics it may enter (the live tau_ss gate ahead of the enhancer); None: all.
        ``judge``: the dive outside the pipeline whose pre-samplers score (the live raw gate's); it takes the frames
        in unless ``seen`` gives their rows: the frames are copies of frames a dive already saw (the live enhanced
        copies: their raw frames' rows), judged by those frames' place in it. Neither: this pipeline's dive."""
        n = len(frames)
        if seen is not None and len(seen.centred) != n:
            raise ValueError(f"seen has {len(seen.centred)} rows for {n} frames")
        if n == 0:
            return BatchOutcome([], [])
        self.counts["frames"] += n
        if gated:  # an outside gate (the decode thread's, the live selective stage's) already chose
            if prepared is None:
                raise ValueError("gated=True needs the prepared images (None marks a skipped frame)")
            keep = np.array([p is not None for p in prepared], dtype=bool)
        elif not self.gate.on:
            self.gate.seen += n
            self.gate.encoded += n
            return self._process_encoded(frames, prepared, poses, only, seen, judge)
        else:
            with self.clock.stage("gate", n):
                views = prepared if prepared is not None else [f.image for f in frames]
                keep = self.gate.admit_batch(list(views), [f.time_s for f in frames])
        go = np.flatnonzero(keep)
        self.counts["skipped"] += n - len(go)
        if len(go) == n:
            return self._process_encoded(frames, prepared, poses, only, seen, judge)
        results = [FrameResult(f.index, f.time_s, float("nan"), False, encoded=False) for f in frames]
        if len(go) == 0:
            return BatchOutcome(results, [])
        outcome = self._process_encoded([frames[i] for i in go],
                                        None if prepared is None else [prepared[i] for i in go],
                                        None if poses is None else [poses[i] for i in go],
                                        None if only is None else [only[i] for i in go],
                                        None if seen is None else seen.rows(go), judge)
        for i, result in zip(go, outcome.results, strict=True):
            results[i] = result
        return BatchOutcome(results, outcome.events)

    def _process_encoded(self, frames: Sequence[Frame], prepared: Sequence[np.ndarray] | None,
                         poses: Sequence[Pose | None] | None,
                         only: Sequence[Collection[str]] | None = None, seen: DiveFrames | None = None,
                         judge: OuterDive | None = None) -> BatchOutcome:
        """Every stage after the gate, for the frames it let through."""
        n = len(frames)
        images = [f.image for f in frames]
        if self.enhance_mode == "always":
            with self.clock.stage("enhance", n):
                images = [self.enhancer.enhance(img) for img in images]
            prepared = None
        if prepared is None:
            with self.clock.stage("prepare", n):
                prepared = [self.prepare(img) for img in images]
        emb = self._encode(prepared, "encode")
        names = [t.name for t in self.topics]
        with self.clock.stage("score", n):
            pooled = self.encoder.sampler_features(emb)  # the dive's and the sampler's features, asked for once
            if seen is not None:  # copies: judged by their frames' place in the dive that saw them
                frames_in_dive = seen.copies()
            elif judge is not None:
                frames_in_dive = judge.take(emb)
            else:
                frames_in_dive = self.dive.take(pooled, scene=self.encoder.scene_input(emb), embeddings=emb)
            scores, passed = self._score(emb, frames_in_dive, judge)
            if only is not None:
                passed &= np.array([[t.name in allowed for t in self.topics] for allowed in only],
                                   dtype=bool).reshape(passed.shape)
        results = [FrameResult(f.index, f.time_s, float(row.max()), bool(ok.any()),
                               enhanced=self.enhance_mode == "always",
                               topic_scores={name: float(v) for name, v in zip(names, row, strict=True)})
                   for f, row, ok in zip(frames, scores, passed, strict=True)]
        self.counts["encoded"] += n
        self.counts["passed"] += int(passed.any(axis=1).sum())

        final_images = list(images)
        final_scores = scores.astype(np.float64)
        if self.enhance_mode == "selective" and passed.any():
            passed, pooled, final_images, final_scores = self._enhance_selected(frames, passed, frames_in_dive, judge,
                                                                                pooled, results, final_images,
                                                                                final_scores)
        events: list[SummaryEvent] = []
        go = np.flatnonzero(passed.any(axis=1))
        if len(go):
            with self.clock.stage("sample", len(go)):
                feats = dist.prepare_features(pooled[go])
                for row, i in enumerate(go):
                    results[i].offered = True
                    self.counts["offered"] += 1
                    for t in np.flatnonzero(passed[i]):
                        events.extend(self._offer(self.topics[t], frames[i], results[i], feats[row],
                                                  final_images[i], final_scores[i, t],
                                                  poses[i] if poses is not None else None))
        events.extend(stand_in_events(self.topics, self.indices, frames, results, pooled, passed, final_scores,
                                      final_images, poses, self.enhance_mode, self.quiet_s))
        return BatchOutcome(results, events)

    @property
    def next_image_index(self) -> int:
        return self.indices.next

    @next_image_index.setter
    def next_image_index(self, value: int) -> None:
        self.indices.next = int(value)

    @property
    def indices_used_up(self) -> bool:
        """Every image index MAVLink can carry was handed out: no new frame can enter (``image_indices``)."""
        return self.indices.used_up

    def finish(self) -> list[SummaryEvent]:
        """End of the footage: an empty topic shows its best frames now, however short the quiet period was."""
        return finish_events(self.topics, self.indices)

    def _score(self, emb: np.ndarray, frames: DiveFrames, judge: OuterDive | None,
               tau: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Every topic's scores (by the judging dive's pre-samplers, if any) and passes (by this pipeline's)."""
        scorers = None if judge is None else [judge.scorer(t.name) for t in self.topics]
        return score_matrix([t.presampler for t in self.topics], emb, frames, tau, scorers)

    def _enhance_selected(self, frames, passed, in_dive, judge, pooled, results, images, scores):
        """MERLION-E: enhance the frames that passed (any topic), re-encode them once, keep per topic those whose
        ss_e passes tau_ses. A copy is not a frame of the dive: it is judged by its raw frame's place in it, the
        scene residual and the features the marks read (the enhancer changes every pixel: against the dive every
        copy would look new); only the query is asked of the copy itself."""
        go = np.flatnonzero(passed.any(axis=1))
        with self.clock.stage("enhance", len(go)):
            enhanced = [self.enhancer.enhance(frames[i].image) for i in go]
        small = [self.prepare(img) for img in enhanced]
        emb_e = self._encode(small, "reencode")
        pooled_e = self.encoder.sampler_features(emb_e)
        ss_e, ok = self._score(emb_e, in_dive.rows(go).copies(), judge, self._tau_ses)
        ok &= passed[go]
        self.counts["enhanced"] += len(go)
        self.counts["enhanced_passed"] += int(ok.any(axis=1).sum())
        passed = np.zeros_like(passed)
        scores = scores.copy()
        for row, i in enumerate(go):
            results[i].enhanced = True
            results[i].enhanced_score = float(ss_e[row].max())
            images[i] = enhanced[row]
            scores[i] = ss_e[row]
            passed[i] = ok[row]
        # the sampler compares enhanced embeddings: rows of frames that go on are replaced by theirs
        pooled = np.array(pooled, copy=True)
        pooled[go] = pooled_e
        return passed, pooled, images, scores

    def _offer(self, topic: Topic, frame: Frame, result: FrameResult, feature: np.ndarray, image: np.ndarray,
               score: float, pose: Pose | None) -> list[SummaryEvent]:
        if not self.indices.left():
            return []
        key = self.indices.next
        decision = topic.sampler.offer(key, feature, prepared=True)
        if not decision.added:
            self.counts["duplicates"] += decision.duplicate
            return []
        self.indices.take()
        self.counts["added"] += 1
        if not result.added:
            result.added, result.image_index = True, key
        result.added_to.append(topic.name)
        raw_image, raw_score = raw_behind(frame, image, result, topic.name, self.enhance_mode)
        held = SummaryFrame(
            image_index=key, frame_index=frame.index, time_s=frame.time_s, capture_time=frame.capture_time,
            score=float(score), image=image, feature=feature.copy(), pose=pose,
            raw_image=raw_image, enhanced=raw_image is not None, topic=topic.name, raw_score=raw_score,
        )
        topic.held[key] = held
        keys = self._all_keys()
        events = [SummaryEvent("added", held, list(keys))]
        events.extend(SummaryEvent("removed", topic.held.pop(k), list(keys)) for k in decision.removed)
        return events
