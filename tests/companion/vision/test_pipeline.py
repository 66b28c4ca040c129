"""The pipeline on real frames with the packaged encoder: results, events, indices, resume, live K, MERLION-E."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import Config, EncoderConfig
from companion.sources.frame_feed import FrameFeed
from companion.sources.video import VideoSource
from companion.vision.dive_mean import DiveFrames
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.enhancers.base import Enhancer
from companion.vision.feedback import MarkedPreSampler, Marks
from companion.vision.pipeline import Pipeline, downscale_for
from companion.vision.scene_memory import SceneMemory
from tests.companion.vision.helpers import replay_events, run, survey_marks
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def encoder():
    return ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False)


@pytest.fixture(scope="module")
def frames():
    return list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=2))  # 19 frames over both fish segments


def make(encoder, k=3, tau=0.25, first=0, gate="none", **enhance):
    """Ungated by default: these tests are about the stages after the frame gate (tests/.../test_gate.py)."""
    cfg = Config.model_validate({"sampler": {"k": k}, "queries": {"tau_ss": tau}, "enhance": enhance,
                                 "gate": {"mode": gate}})
    return Pipeline.from_config(cfg, encoder, first_image_index=first)


@pytest.fixture(scope="module")
def baseline(encoder, frames):
    pipe = make(encoder, first=100)
    results, events = run(pipe, frames)
    return pipe, results, events


def test_results_follow_the_frames_and_the_threshold(baseline, frames):
    pipe, results, _ = baseline
    assert all(f.raw_score is None for f in pipe.summary)  # nothing enhanced: the score is the raw frame's
    assert [r.frame_index for r in results] == [f.index for f in frames]
    assert all(r.passed == (r.score > 0.25) for r in results)
    assert all(r.offered == r.passed for r in results)
    assert any(r.passed for r in results) and not all(r.passed for r in results)
    assert not any(r.added and not r.passed for r in results)
    assert pipe.counts["frames"] == len(frames) and pipe.counts["passed"] == sum(r.passed for r in results)


def test_events_replay_to_the_summary_with_running_indices(baseline):
    pipe, results, events = baseline
    assert replay_events(events) == [f.image_index for f in pipe.summary] == pipe.sampler.keys
    added = [r.image_index for r in results if r.added]
    assert added == list(range(100, 100 + len(added)))  # running index, never reused
    assert len(pipe.summary) == 3
    for f in pipe.summary:
        assert f.image.shape == (270, 480, 3)  # full resolution, not the encoder's copy
        assert f.feature.ndim == 1 and np.isclose(np.linalg.norm(f.feature), 1.0)
        assert f.score > 0.25 and not f.enhanced


def test_batching_and_the_decode_thread_give_the_same_summary(encoder, baseline):
    pipe, results, _ = baseline
    other = make(encoder, first=100)
    got = []
    with FrameFeed(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=2), other.prepare) as feed:
        for batch in feed.batches(5):
            got += other.process([f for f, _ in batch], [s for _, s in batch]).results
    assert [r.frame_index for r in got] == [r.frame_index for r in results]
    assert np.allclose([r.score for r in got], [r.score for r in results], atol=1e-4)
    assert other.sampler.keys == pipe.sampler.keys


def test_restore_resumes_with_the_same_summary_and_higher_indices(encoder, frames, baseline):
    pipe, _, _ = baseline
    first = make(encoder, first=100)
    run(first, frames[:10])
    resumed = make(encoder)
    resumed.restore(first.summary)
    assert resumed.next_image_index == first.next_image_index
    run(resumed, frames[10:])
    assert resumed.sampler.keys == pipe.sampler.keys


def test_changing_k_and_tau_while_running(encoder, frames):
    pipe = make(encoder, k=4)
    run(pipe, frames[4:14])
    before = pipe.sampler.keys
    events = pipe.set_k(2)
    assert [e.kind for e in events] == ["removed", "removed"]
    assert len(pipe.summary) == 2 and pipe.sampler.keys[-1] == before[-1]
    pipe.tau_ss = 99.9
    out = pipe.process(frames[6:8])
    assert not any(r.passed for r in out.results) and out.events == []


def test_downscale_keeps_aspect_and_covers_the_input():
    img = np.zeros((1080, 1920, 3), np.uint8)
    assert downscale_for(img, (224, 224)).shape == (224, 398, 3)
    small = np.zeros((100, 120, 3), np.uint8)
    assert downscale_for(small, (224, 224)) is small


class CountingEnhancer(Enhancer):
    """The real classic enhancer, counting the frames it is given (selective mode must skip failures)."""

    def __init__(self, inner: Enhancer) -> None:
        self.inner, self.name, self.seen = inner, inner.name, 0

    def enhance(self, image):
        self.seen += 1
        return self.inner.enhance(image)


def test_selective_enhancement_only_touches_passing_frames(encoder, frames):
    pipe = make(encoder, mode="selective", tau_ses=0.3)
    pipe.enhancer = CountingEnhancer(pipe.enhancer)
    results, _ = run(pipe, frames[4:12])
    assert 0 < pipe.enhancer.seen < len(results)
    assert pipe.enhancer.seen == sum(r.passed for r in results)
    assert pipe.summary, "some enhanced frame should pass tau_ses"
    assert all(r.enhanced == r.passed for r in results)
    assert all(r.offered == (r.passed and r.enhanced_score > 0.3) for r in results)
    by_index = {r.frame_index: r for r in results}
    for f in pipe.summary:
        assert f.enhanced and f.raw_image is not None and f.image is not f.raw_image
        assert f.score > 0.3  # ss_e
        # the raw frame's ss_t is kept beside it: the gate it passed before the enhancer
        assert f.raw_score == by_index[f.frame_index].topic_scores[f.topic] > 0.25
        assert f.raw_score != f.score
    strict = make(encoder, mode="selective", tau_ses=0.999)
    results, events = run(strict, frames[4:8])
    assert events == [] and not any(r.offered for r in results)


def test_an_enhanced_stand_in_keeps_its_raw_frame_and_ss_t(encoder, frames):
    """No copy passes tau_ses: the frames shown below the threshold are enhanced copies, each with its frame as
    captured and that frame's ss_t beside the copy's score."""
    cfg = Config.model_validate({"sampler": {"k": 3}, "gate": {"mode": "none"},
                                 "queries": {"tau_ss": 0.25, "below_threshold_after_s": 0},
                                 "enhance": {"mode": "selective", "tau_ses": 0.999}})
    pipe = Pipeline.from_config(cfg, encoder)
    results, events = run(pipe, frames[4:12])
    by_index = {r.frame_index: r for r in results}
    shown = [e.frame for e in events if e.kind == "added"]
    assert shown and all(f.below_threshold for f in shown)
    for f in shown:
        assert f.enhanced and f.raw_image is not None and f.image is not f.raw_image
        assert f.score == pytest.approx(by_index[f.frame_index].enhanced_score)  # the copy's ss_e
        assert f.raw_score == by_index[f.frame_index].topic_scores[f.topic] != f.score


def test_always_enhances_every_frame(encoder, frames):
    pipe = make(encoder, mode="always")
    out = pipe.process(frames[:2])
    assert all(r.enhanced for r in out.results)
    assert pipe.clock.items["enhance"] == 2


def test_the_default_gate_skips_frames_of_the_survey_but_keeps_both_fish_segments(encoder):
    """At the native 10 frames/s the gate skips near-duplicates; the summary still holds frames of both fish
    segments (frames 11-40 and 52-81) and none of the no-fish ones."""
    frames = list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=10))
    pipe = make(encoder, k=4, tau=0.25, gate="difference")
    results, _ = run(pipe, frames)
    skipped = sum(not r.encoded for r in results)
    assert 0 < skipped < len(frames) and pipe.counts["skipped"] == skipped
    assert pipe.counts["frames"] == len(frames) == len(results)
    held = sorted(f.frame_index for f in pipe.summary)
    assert any(11 <= i <= 40 for i in held) and any(52 <= i <= 81 for i in held)


def test_gating_in_the_decode_thread_fills_batches_and_gives_the_same_summary(encoder):
    """FrameFeed(gate=...) decides in the decode thread: skipped frames ride along as (frame, None) and only the
    frames to encode count toward the batch; the results are those of gating inside Pipeline.process."""
    video = shared_file("survey/survey_480x270.mp4")
    inline = make(encoder, k=4, gate="difference")
    expected = []
    with FrameFeed(VideoSource(video, fps=10), inline.prepare) as feed:
        for batch in feed.batches(4):
            expected += inline.process([f for f, _ in batch], [s for _, s in batch]).results
    fed = make(encoder, k=4, gate="difference")
    got, sizes = [], []
    with FrameFeed(VideoSource(video, fps=10), fed.prepare, gate=fed.gate) as feed:
        assert feed.gated
        for batch in feed.batches(4):
            sizes.append(sum(s is not None for _, s in batch))
            got += fed.process([f for f, _ in batch], [s for _, s in batch], gated=True).results
    assert [r.frame_index for r in got] == [r.frame_index for r in expected]
    assert [r.encoded for r in got] == [r.encoded for r in expected]
    assert [r.added for r in got] == [r.added for r in expected]
    assert max(sizes) == 4 and fed.counts == inline.counts
    assert [f.frame_index for f in fed.summary] == [f.frame_index for f in inline.summary]


def test_an_enhanced_copy_is_judged_by_its_raw_frames_scene_residual_and_does_not_join_the_dive(frames):
    """With the scene head (region views), selective enhancement scores each passing frame's copy by the frame's
    own scene residual: the head learned raw frames against dives of raw frames, and the enhancer changes every
    pixel, so judged against the dive every copy would look new."""
    calls: list[tuple[int, bool]] = []

    class Recording(SceneMemory):
        def residuals(self, scene, *, join=True):
            calls.append((len(scene), join))
            return super().residuals(scene, join=join)

    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", batch=8))  # regions: the scene head loads
    pipe = make(encoder, mode="selective", tau_ses=0.3, tau=0.05)
    pipe.dive.scene = Recording()
    results, _ = run(pipe, frames[4:12])
    enhanced = [r for r in results[1:] if r.enhanced]  # the dive's first frame has no scene: the pooled head
    assert enhanced and all(r.enhanced_score == pytest.approx(r.score, abs=1e-6) for r in enhanced)
    if results[0].enhanced:  # no scene before it: the pooled head scores the copy itself
        assert results[0].enhanced_score != results[0].score
    # the copies never reached the dive's scene memory: every frame joined it once, nothing else was asked
    assert all(join for _n, join in calls) and sum(n for n, _join in calls) == len(results)
    assert pipe.dive.frames == len(results)  # nor its mean
    plain = make(ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False), mode="selective",
                 tau_ses=0.3, tau=0.05)  # no scene head: the copy is scored itself
    results, _ = run(plain, frames[4:12])
    assert any(r.enhanced and abs(r.enhanced_score - r.score) > 1e-5 for r in results)


@pytest.mark.parametrize("n", [3, 1], ids=["centred-marks", "nearest-centroid"])
def test_with_marks_an_enhanced_copy_is_judged_by_its_raw_frames_place_in_the_dive(frames, n):
    """The dive-centred marks read a frame's features minus the dive's mean, the nearest-centroid rule (one mark
    a side) its most query-like region. A copy's own features carry the enhancer's colours, which no raw frame of
    the dive and no mark has, so it is judged by its raw frame's row: with the marks in force and the scene head
    answering, ss_e is ss_t exactly."""
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", batch=8))  # regions: the scene head loads
    pipe = make(encoder, mode="selective", tau_ses=0.3, tau=0.05)
    run(pipe, frames[:8])
    like, unlike = survey_marks(frames, n)
    pipe.presampler = MarkedPreSampler(pipe.presampler,
                                       Marks.from_images(encoder, [pipe.prepare(i) for i in like],
                                                         [pipe.prepare(i) for i in unlike],
                                                         pipe.presampler.text_embeddings))
    rule = pipe.presampler.centred_trust if n > 1 else pipe.presampler.weight
    assert rule > 0  # the marks are in force, by the rule the test names
    results, _ = run(pipe, frames[8:])
    enhanced = [r for r in results if r.enhanced]
    assert len(enhanced) >= 3, results
    assert all(r.enhanced_score == pytest.approx(r.score, abs=1e-6) for r in enhanced), enhanced
    assert pipe.dive.frames == len(frames)  # the copies did not join the dive


def test_rows_given_by_the_caller_follow_the_frames_a_gate_lets_through(frames):
    """``process(seen=...)``: each frame is judged by the row given for it (its scene residual here), also when a
    caller's gate skipped some frames (the rows of the frames it let through, in order), and never joins the
    pipeline's own dive."""
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", batch=8))
    pipe = make(encoder, tau=0.0)
    batch = frames[4:10]
    emb = encoder.encode_images([pipe.prepare(f.image) for f in batch])
    views = SceneMemory().residuals(encoder.scene_input(emb))
    rows = views[::-1].copy()  # any finite rows: reversed, so a row used for the wrong frame shows
    rows[-1] = rows[0]  # the last row (the first frame's, NaN) replaced by a finite one
    pooled = encoder.sampler_features(emb)
    seen = DiveFrames(pooled, np.zeros(pooled.shape), True, rows)
    prepared = [pipe.prepare(f.image) if i % 3 else None for i, f in enumerate(batch)]  # the gate skips 0 and 3
    outcome = pipe.process(batch, prepared, gated=True, seen=seen)
    head = next(h for h in encoder.heads if h.input == "scene")
    for i, result in enumerate(outcome.results):
        if i % 3 == 0:
            assert not result.encoded
        else:
            assert result.score == pytest.approx(float(head.probabilities(rows[i:i + 1])[0]), abs=1e-6)
    assert pipe.dive.frames == 0 and not pipe.dive.seen
    with pytest.raises(ValueError, match="seen has 2 rows for 6 frames"):
        pipe.process(batch, prepared, gated=True, seen=seen.rows([0, 1]))
