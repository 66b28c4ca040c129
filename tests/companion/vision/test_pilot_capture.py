"""The pilot's shutter in the pipeline: the current frame kept whatever its score, never trimmed for room.

The survey video through two topics with K = 2 (so the samplers trim all the time); the pilot presses on a frame
no topic would keep (tau_ss 0.9999: no score passes it), and that frame stays through everything that
trims: more footage, a smaller K, a topic switch, a restart from the store.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import Config, EncoderConfig, StoreConfig
from companion.sources.video import VideoSource
from companion.storage.store import Store
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.pipeline import Pipeline
from companion.vision.topics import TopicSpec
from tests.companion.vision.helpers import replay_events, run
from tests.conftest import shared_file

FISH = {"name": "fish", "positive": "underwater image with fish", "negatives": ["underwater image without fish"]}
CORAL = {"name": "coral", "positive": "underwater image of a coral reef", "negatives": []}


@pytest.fixture(scope="module")
def encoder():
    return ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False)


@pytest.fixture(scope="module")
def frames():
    return list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=4))


def make(encoder, k=2, tau=0.3):
    cfg = Config.model_validate({"sampler": {"k": k}, "queries": {"tau_ss": tau, "topics": [FISH, CORAL]},
                                 "gate": {"mode": "none"}})
    return Pipeline.from_config(cfg, encoder)


def test_a_pilots_frame_is_kept_whatever_its_score_and_never_trimmed(encoder, frames, tmp_path: Path):
    pipe = make(encoder, tau=0.9999)  # nothing passes: only the pilot's press keeps a frame
    store = Store(StoreConfig(dir=str(tmp_path / "store")))
    events = []
    results, got = run(pipe, frames[:8])
    events += got
    assert not any(r.passed for r in results) and got == []
    pressed = frames[5]
    added = pipe.capture(pressed, None)
    events += added
    (event,) = added
    frame = event.frame
    assert event.kind == "added" and frame.pilot and not frame.below_threshold
    assert frame.frame_index == pressed.index and frame.image is pressed.image
    assert frame.image_index == 0 and 0.0 < frame.score < 1.0  # scored like any frame, and kept below the threshold
    scores = results[5].topic_scores
    assert frame.topic == max(scores, key=scores.get)  # filed under the topic that scores it highest
    assert frame.image_index in event.summary
    key = frame.image_index
    for step in (lambda: run(pipe, frames[8:])[1], lambda: pipe.set_k(1),
                 lambda: pipe.set_topics([TopicSpec("wreck", "underwater image of a wreck")])):
        more = step()
        events += more
        assert key in [f.image_index for f in pipe.summary]
        assert all(e.frame.image_index != key for e in more if e.kind == "removed")
        assert all(key in e.summary for e in more)  # every event's summary list, which the store follows, has it
    assert pipe.topic("wreck").pilot == [key] and pipe.topic("wreck").held[key].topic == "wreck"
    assert sorted(replay_events(events)) == sorted(f.image_index for f in pipe.summary)
    # the store keeps it marked, and a restart puts it back outside the sampler
    for e in events:
        store.apply(e)
    assert key in store.summary and store.sidecar(key)["pilot"] is True
    again = make(encoder, k=1)
    removed = again.restore([store.frame(i) for i in store.summary])
    assert key not in [e.frame.image_index for e in removed]
    assert store.sidecar(key)["topic"] == "wreck"  # no longer followed: filed under the default (first) topic
    assert [t.name for t in again.topics if key in t.pilot] == ["fish"]
    assert all(key not in t.sampler.keys for t in again.topics)
    _, more = run(again, frames[:16])
    assert key in [f.image_index for f in again.summary] and all(key in e.summary for e in more)
