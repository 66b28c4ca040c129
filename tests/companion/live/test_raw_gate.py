"""enhance.mode selective with several topics: the raw tau_ss gate scores every topic on the one embedding.

On the survey video with the packaged encoder: a frame is a candidate for the enhancer when any topic passes,
it carries the topics it passed for, and after enhancement the pipeline offers it to those topics only.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from companion.config import Config, EncoderConfig, StoreConfig
from companion.live.control.marks import marked
from companion.live.enhance_worker import EnhanceWorker, SelectiveStage
from companion.live.health import Health
from companion.live.loops import InferenceLoop, LiveCounters
from companion.live.queues import DropOldestQueue
from companion.live.raw_gate import RawGate
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.video import VideoSource
from companion.storage.store import Store
from companion.vision.encoders.counted import CountedEncoder
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.enhancers.classic import ClassicEnhancer
from companion.vision.feedback import Marks
from companion.vision.pipeline import Pipeline
from companion.vision.presampler import PreSampler
from companion.vision.topics import TopicSpec
from tests.companion.vision.helpers import survey_marks
from tests.conftest import shared_file

FISH = TopicSpec("fish", "underwater image with fish", ("underwater image without fish",), 0.5)
CORAL = TopicSpec("coral", "underwater image of a coral reef", ("underwater image without coral",), 0.2)


@pytest.fixture(scope="module")
def encoder():
    return CountedEncoder(ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False))


@pytest.fixture(scope="module")
def frames():
    return list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=2))


def _pipeline(encoder, tau: float = 0.3) -> Pipeline:
    cfg = Config.model_validate({"sampler": {"k": 50}, "gate": {"mode": "none"}, "queries": {"tau_ss": tau, "topics": [
        {"name": "fish", "positive": FISH.positive, "negatives": list(FISH.negatives)},
        {"name": "coral", "positive": CORAL.positive, "negatives": list(CORAL.negatives)}]}})
    return Pipeline.from_config(cfg, encoder)


def test_every_topic_is_scored_on_one_embedding_and_a_frame_goes_on_for_any(encoder, frames) -> None:
    pipeline = _pipeline(encoder)
    gate = RawGate(encoder, [FISH, CORAL], tau_ss=0.5)
    stage = SelectiveStage(pipeline, gate, enhancer=None, queue_size=len(frames), lock=threading.RLock())
    before = encoder.images
    out = stage.score(frames, None)
    assert encoder.images - before == len(frames)  # one pass for both topics

    emb = encoder.encode_images([pipeline.prepare(f.image) for f in frames])
    alone = {spec.name: PreSampler(encoder, spec.positive, spec.negatives, spec.tau_ss) for spec in (FISH, CORAL)}
    scores = {name: p.scores(emb) for name, p in alone.items()}
    want = [tuple(n for n in ("fish", "coral") if scores[n][i] > alone[n].tau_ss) for i in range(len(frames))]
    assert len(set(want)) >= 3, want  # frames passing one topic, the other, both or none: the case is real
    queued = stage.queue.get_batch(len(frames), timeout=0.1)
    assert [tuple(c.topics) for c in queued] == [w for w in want if w]
    kept = [i for i, w in enumerate(want) if w]
    for c, i in zip(queued, kept, strict=True):  # each with its ss_t per topic: stored beside the enhanced copy's
        np.testing.assert_allclose([c.topics[n] for n in want[i]], [scores[n][i] for n in want[i]], rtol=1e-5)
    assert [passed for _f, _s, passed, _e in out] == [bool(w) for w in want]
    assert all(encoded for *_rest, encoded in out)  # no frame gate given: every frame scored
    best = np.maximum(scores["fish"], scores["coral"])
    np.testing.assert_allclose([s for _f, s, _p, _e in out], best, rtol=1e-5)


def _worker_events(encoder, frames, tmp_path, *, tau_ses: float, quiet_s: float | None = None):
    """Two topics through the live selective stage: the candidates and the summary events of their copies."""
    queries = {"tau_ss": tau_ses, "topics": [
        {"name": "fish", "positive": FISH.positive, "negatives": list(FISH.negatives)},
        {"name": "coral", "positive": CORAL.positive, "negatives": list(CORAL.negatives)}]}
    if quiet_s is not None:
        queries["below_threshold_after_s"] = quiet_s
    cfg = Config.model_validate({"sampler": {"k": 50}, "gate": {"mode": "none"}, "queries": queries})
    pipeline = Pipeline.from_config(cfg, encoder)
    events: list = []
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {},
                           publish=events.append)
    stage = SelectiveStage(pipeline, RawGate(encoder, [FISH, CORAL], tau_ss=0.5), enhancer=ClassicEnhancer(),
                           queue_size=len(frames), lock=keeper.lock)
    stage.score(frames, None)
    candidates = stage.queue.get_batch(len(frames), timeout=0.1)
    worker = EnhanceWorker(stage, Health(10.0), LiveCounters(), threading.Event(), batch=8, keeper=keeper)
    added = []  # (the batch it was added in, the frame)
    for at in range(0, len(candidates), 4):  # batches of four: stand-ins may be shown a batch after their own
        worker.step(candidates[at:at + 4])
        added += [(at // 4, e.frame) for e in events[len(added):] if e.kind == "added"]
        del events[:]
    return {c.frame.index: (n // 4, c) for n, c in enumerate(candidates)}, added


def test_an_enhanced_frame_keeps_its_raw_frame_and_ss_t_for_the_topic_it_entered(encoder, frames, tmp_path):
    by_index, added = _worker_events(encoder, frames, tmp_path, tau_ses=0.0)
    assert {f.topic for _, f in added} == {"fish", "coral"}, added  # the pairing is tested with both topics
    for _, f in added:
        _, candidate = by_index[f.frame_index]
        assert f.enhanced and f.raw_image is candidate.frame.image and f.image is not f.raw_image
        assert f.raw_score == candidate.topics[f.topic]  # this topic's ss_t, not the frame's best


def test_an_enhanced_stand_in_shown_a_batch_later_keeps_its_raw_frame_and_ss_t(encoder, frames, tmp_path):
    by_index, added = _worker_events(encoder, frames, tmp_path, tau_ses=0.999, quiet_s=3.0)
    assert added and all(f.below_threshold for _, f in added)  # no copy passes 0.999: only stand-ins are shown
    assert any(by_index[f.frame_index][0] < batch for batch, f in added), "none shown after its own batch"
    for _, f in added:
        _, candidate = by_index[f.frame_index]
        assert f.enhanced and f.raw_image is candidate.frame.image
        assert f.raw_score == candidate.topics.get(f.topic)  # None for a topic its raw frame did not pass


def test_the_gate_follows_query_changes_and_tau_for_every_topic(encoder) -> None:
    gate = RawGate(encoder, [FISH, CORAL], tau_ss=0.4)
    fish = gate.presamplers["fish"]
    gate.set_topics([TopicSpec("fish", "underwater image of fish", ("underwater image without fish",)),
                     TopicSpec("wreck", "underwater image of a wreck", ("underwater image without a wreck",))])
    assert gate.names == ["fish", "wreck"]
    assert gate.presamplers["fish"] is fish and fish.positive == "underwater image of fish"  # kept: marks too
    assert fish.tau_ss == 0.5 and gate.tau_of("wreck") == 0.4  # its own tau stays; a new one takes the default
    assert all(p.dive is gate.dive for p in gate.presamplers.values())  # one dive for every topic, new ones too
    gate.tau_ss = 0.3  # MERL_TAU_SS
    assert [p.tau_ss for p in gate.presamplers.values()] == [0.3, 0.3] and gate.tau_ss == 0.3


def test_after_enhancement_a_frame_enters_only_the_topics_it_passed_for(frames) -> None:
    pipeline = _pipeline(VisualEncoder(), tau=0.0)  # no text tower: every frame passes every topic by itself
    outcome = pipeline.process(frames[:4], only=[("fish",), ("coral",), (), ("fish", "coral")])
    assert [r.added_to for r in outcome.results] == [["fish"], ["coral"], [], ["fish", "coral"]]
    assert [r.passed for r in outcome.results] == [True, True, False, True]
    assert {e.frame.topic for e in outcome.events if e.frame.frame_index == frames[0].index} == {"fish"}


def test_an_enhanced_candidate_is_judged_by_the_raw_dives_scene_residual(frames, tmp_path) -> None:
    """Live, the enhanced copies go through a pipeline of their own whose dive holds only candidates; each
    carries the scene residual the raw gate's dive gave its frame and is scored by it (the scene head's "fish"),
    as the offline pipeline does, instead of against a dive of other candidates."""
    encoder = CountedEncoder(ImageNetEncoder(EncoderConfig(name="imagenet", batch=8)))  # regions: scene head
    cfg = Config.model_validate({"sampler": {"k": 50}, "gate": {"mode": "none"}, "queries": {"tau_ss": 0.0, "topics": [
        {"name": "fish", "positive": FISH.positive, "negatives": list(FISH.negatives)}]}})
    pipeline = Pipeline.from_config(cfg, encoder)  # behind the enhancer, its gate (tau_ses here) 0: all go on
    raw = RawGate(encoder, [FISH], tau_ss=0.05)
    events: list = []
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {},
                           publish=events.append)
    stage = SelectiveStage(pipeline, raw, enhancer=ClassicEnhancer(), queue_size=len(frames), lock=keeper.lock)
    stage.score(frames, None)
    candidates = stage.queue.get_batch(len(frames), timeout=0.1)
    assert len(candidates) >= 4 and all(c.seen is not None and c.seen.scene is not None for c in candidates)
    first = candidates[0].frame.index == frames[0].index  # the raw dive's first frame has no scene
    assert np.isnan(candidates[0].seen.scene).all() == first
    worker = EnhanceWorker(stage, Health(10.0), LiveCounters(), threading.Event(), batch=8, keeper=keeper)
    worker.step(candidates)
    raw_score = {c.frame.index: c.score for c in candidates[1 if first else 0:]}
    added = {e.frame.frame_index: e.frame.score for e in events if e.kind == "added"}
    judged = {i: v for i, v in added.items() if i in raw_score}
    assert len(judged) >= 2, (added, raw_score)
    assert all(v == pytest.approx(raw_score[i], abs=1e-6) for i, v in judged.items()), (judged, raw_score)
    assert all(e.frame.enhanced for e in events if e.kind == "added")


@pytest.mark.parametrize("n", [3, 1], ids=["centred-marks", "nearest-centroid"])
def test_with_marks_an_enhanced_candidate_is_scored_by_the_raw_dives_marks(frames, tmp_path, n) -> None:
    """The surface's marks wrap both the raw gate's pre-samplers and the pipeline's (``MarksHandler``). The copies
    are scored by the raw gate's, in the dive of raw frames, from the row their frame had there (its features and
    embedding): with the scene head answering, ss_e is ss_t by either rule; the enhancer's pipeline keeps no dive
    of candidates."""
    encoder = CountedEncoder(ImageNetEncoder(EncoderConfig(name="imagenet", batch=8)))  # regions: scene head
    cfg = Config.model_validate({"sampler": {"k": 50}, "gate": {"mode": "none"}, "queries": {"tau_ss": 0.0, "topics": [
        {"name": "fish", "positive": FISH.positive, "negatives": list(FISH.negatives)}]}})
    pipeline = Pipeline.from_config(cfg, encoder)
    raw = RawGate(encoder, [FISH], tau_ss=0.05)
    events: list = []
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {},
                           publish=events.append)
    stage = SelectiveStage(pipeline, raw, enhancer=ClassicEnhancer(), queue_size=len(frames), lock=keeper.lock)
    worker = EnhanceWorker(stage, Health(10.0), LiveCounters(), threading.Event(), batch=8, keeper=keeper)
    stage.score(frames[:8], None)
    worker.step(stage.queue.get_batch(len(frames), timeout=0.1))
    like, unlike = survey_marks(frames, n)
    marks = Marks.from_images(encoder, [pipeline.prepare(i) for i in like], [pipeline.prepare(i) for i in unlike],
                              raw.presamplers["fish"].text_embeddings)
    raw.presamplers["fish"] = marked(raw.presamplers["fish"], marks)  # as MarksHandler._apply does
    pipeline.topics[0].presampler = marked(pipeline.topics[0].presampler, marks)
    gate = raw.presamplers["fish"]
    assert (gate.centred_trust if n > 1 else gate.weight) > 0  # the marks are in force, by the rule named
    events.clear()
    stage.score(frames[8:], None)
    candidates = stage.queue.get_batch(len(frames), timeout=0.1)
    worker.step(candidates)
    raw_score = {c.frame.index: c.score for c in candidates}
    added = {e.frame.frame_index: e.frame.score for e in events if e.kind == "added"}
    assert len(added) >= 3 and set(added) <= set(raw_score), (added, raw_score)
    assert all(v == pytest.approx(raw_score[i], abs=1e-6) for i, v in added.items()), (added, raw_score)
    assert raw.dive.frames == len(frames) and pipeline.dive.frames == 0


def test_with_the_enhancer_off_the_frames_are_judged_by_the_same_dive_of_raw_frames(frames, tmp_path) -> None:
    """MERL_ENHANCE 0 sends frames straight to the enhancer's pipeline: they are still judged by, and taken
    into, the raw gate's dive, so switching the enhancer off and on never restarts or freezes the dive."""
    encoder = CountedEncoder(ImageNetEncoder(EncoderConfig(name="imagenet", batch=8)))  # regions: scene head
    cfg = Config.model_validate({"sampler": {"k": 50}, "gate": {"mode": "none"}, "queries": {"tau_ss": 0.05, "topics": [
        {"name": "fish", "positive": FISH.positive, "negatives": list(FISH.negatives)}]}})
    pipeline = Pipeline.from_config(cfg, encoder)
    raw = RawGate(encoder, [FISH], tau_ss=0.05)
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {})
    stage = SelectiveStage(pipeline, raw, enhancer=ClassicEnhancer(), queue_size=len(frames), lock=keeper.lock)
    counters = LiveCounters()
    loop = InferenceLoop(pipeline, DropOldestQueue(8), Health(10.0), counters, threading.Event(), batch=8,
                         pose_at=None, keeper=keeper, selective=stage)
    loop.step(frames[:8])  # enhancer on: the raw gate scores
    stage.on = False  # MERL_ENHANCE 0
    loop.step(frames[8:14])
    off = counters.last_score  # frame 13's, from the pipeline
    stage.on = True
    loop.step(frames[14:18])
    assert raw.dive.frames == 18 and counters.frames_scored == 18
    # one continuous dive of the same frames, scored alone: both phases match it
    alone = PreSampler(encoder, FISH.positive, FISH.negatives).scores(
        encoder.encode_images([pipeline.prepare(f.image) for f in frames[:18]]))
    assert off == pytest.approx(float(alone[13]), abs=1e-5)
    assert counters.last_score == pytest.approx(float(alone[17]), abs=1e-5)
    assert len({round(float(v), 3) for v in alone[8:18]}) > 2  # the scores differ from frame to frame
