"""A dive is never silently empty: stand-in frames while nothing passes, on the survey video's real frames."""

from __future__ import annotations

import pytest

from companion.config import Config, EncoderConfig
from companion.sources.video import VideoSource
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.pipeline import Pipeline
from tests.companion.vision.helpers import replay_events, run
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def encoder():
    # the lexical class mapping (no learned head): these tests are about the stand-ins, on scores that rise slowly
    return ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False, heads=False)


@pytest.fixture(scope="module")
def frames():
    # 0.5 s apart; "fish" scores under 0.25 for the first 2 s, then the first fish passes at 2.0 s
    return list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=2))


def make(encoder, tau: float, quiet_s: float, first: int = 0) -> Pipeline:
    cfg = Config.model_validate({"sampler": {"k": 3}, "gate": {"mode": "none"},
                                 "queries": {"tau_ss": tau, "below_threshold_after_s": quiet_s}})
    return Pipeline.from_config(cfg, encoder, first_image_index=first)


def test_stand_ins_show_while_nothing_passes_and_the_first_pass_displaces_them(encoder, frames):
    pipe = make(encoder, tau=0.25, quiet_s=0.0)
    results, events = run(pipe, frames, batch=2)
    first_pass = next(r for r in results if r.passed)
    before = [e for e in events if e.frame.time_s < first_pass.time_s]
    shown = [e.frame for e in before if e.kind == "added"]
    assert shown and all(f.below_threshold and f.score <= 0.25 for f in shown)
    # a better frame of the same moment (within 2 s) replaced the first stand-in: the summary shows the best
    assert [round(f.time_s, 1) for f in shown] == [0.0, 1.5] and shown[1].score > shown[0].score
    gone = [e.frame for e in events if e.kind == "removed" and e.frame.below_threshold]
    assert {id(f) for f in gone} == {id(f) for f in shown}  # every stand-in left once a frame passed
    assert replay_events(events) == [f.image_index for f in pipe.summary] == pipe.sampler.keys
    assert not any(f.below_threshold for f in pipe.summary) and len(pipe.summary) == 3
    assert len({e.frame.image_index for e in events if e.kind == "added"}) == len(
        [e for e in events if e.kind == "added"])  # image indices never reused


def test_stand_ins_wait_for_the_quiet_period_and_finish_shows_them(encoder, frames):
    pipe = make(encoder, tau=0.9, quiet_s=600.0, first=50)
    results, events = run(pipe, frames)
    assert not any(r.passed for r in results) and events == [] and pipe.summary == []  # quiet for 9 s only
    shown = pipe.finish()
    assert [e.kind for e in shown] == ["added"] * len(shown) and 1 <= len(shown) <= 3
    frames_shown = [e.frame for e in shown]
    assert all(f.below_threshold and f.topic == "main" for f in frames_shown)
    assert [f.image_index for f in frames_shown] == list(range(50, 50 + len(shown)))
    times = sorted(f.time_s for f in frames_shown)
    assert all(b - a >= 2.0 for a, b in zip(times, times[1:], strict=False))  # different moments
    best = max(r.score for r in results)
    assert max(f.score for f in frames_shown) == pytest.approx(best)
    assert replay_events(shown) == [f.image_index for f in pipe.summary]


def test_a_restored_stand_in_stays_until_a_frame_passes(encoder, frames):
    pipe = make(encoder, tau=0.25, quiet_s=0.0)
    _, events = run(pipe, frames[:2], batch=2)
    stand_in = pipe.summary[0]
    assert stand_in.below_threshold and [e.kind for e in events] == ["added"]
    again = make(encoder, tau=0.25, quiet_s=0.0)
    assert again.restore([stand_in]) == []
    assert again.summary == [stand_in] and again.sampler.keys == [] and again.next_image_index == 1
    _, later = run(again, frames[2:], batch=2)
    assert any(e.kind == "removed" and e.frame is stand_in for e in later)
    assert not any(f.below_threshold for f in again.summary)
