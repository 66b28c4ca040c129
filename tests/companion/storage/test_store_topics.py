"""A store resumed into a pipeline of topics: each frame back in its topic; a store from before topics, the default.

Real files: frames are stored, the store is opened again as at a restart, and its resume state restores a real
pipeline (the cheap visual encoder) as the live companion does.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from companion.config import Config, StoreConfig
from companion.storage.store import Store
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.events import SummaryEvent, SummaryFrame
from companion.vision.pipeline import Pipeline

FISH = {"name": "fish", "positive": "underwater image with fish", "negatives": ["underwater image without fish"]}
CORAL = {"name": "coral", "positive": "underwater image of a coral reef", "negatives": ["underwater image of sand"]}


def frame(index: int, topic: str) -> SummaryFrame:
    rng = np.random.default_rng(index)
    return SummaryFrame(image_index=index, frame_index=index * 5, time_s=index * 0.5, capture_time=1000.0 + index,
                        score=0.7, image=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
                        feature=rng.random(16).astype(np.float32), topic=topic)


def store_frames(directory: Path, frames: list[SummaryFrame]) -> None:
    store = Store(StoreConfig(dir=str(directory)))
    held: list[int] = []
    for f in frames:
        held.append(f.image_index)
        store.apply(SummaryEvent("added", f, list(held)))


def resumed(directory: Path, topics: list[dict]) -> tuple[Pipeline, list[SummaryEvent]]:
    """What the live companion does at start: open the store, restore its frames into the configured topics."""
    cfg = Config.model_validate({"sampler": {"k": 6}, "queries": {"tau_ss": 0.3, "topics": topics}})
    state = Store(StoreConfig(dir=str(directory))).resume_state()
    pipe = Pipeline.from_config(cfg, VisualEncoder(), first_image_index=state.next_image_index)
    return pipe, pipe.restore(state.frames)


def test_each_topic_resumes_with_its_frames(tmp_path: Path) -> None:
    store_frames(tmp_path, [frame(0, "fish"), frame(1, "coral"), frame(2, "fish"), frame(3, "coral")])
    pipe, removed = resumed(tmp_path, [FISH, CORAL])
    assert removed == []
    assert [f.image_index for f in pipe.topic("fish").summary] == [0, 2]
    assert [f.image_index for f in pipe.topic("coral").summary] == [1, 3]
    assert pipe.next_image_index == 4


def test_a_store_written_before_topics_resumes_into_the_default_topic(tmp_path: Path) -> None:
    store_frames(tmp_path, [frame(0, ""), frame(1, ""), frame(2, "")])
    for path in (tmp_path / "frames").glob("*.json"):  # sidecars as an earlier version wrote them: no "topic"
        sidecar = json.loads(path.read_text())
        del sidecar["topic"]
        path.write_text(json.dumps(sidecar))

    pipe, removed = resumed(tmp_path, [])  # the one default topic, named queries.name
    assert removed == []
    assert [t.name for t in pipe.topics] == ["main"]
    assert [(f.image_index, f.topic) for f in pipe.summary] == [(0, "main"), (1, "main"), (2, "main")]

    pipe, removed = resumed(tmp_path, [FISH, CORAL])  # topics configured since: the first one is the default
    assert removed == []
    assert [f.image_index for f in pipe.topic("fish").summary] == [0, 1, 2]
    assert pipe.topic("coral").summary == []


def test_frames_of_a_topic_no_longer_followed_are_reported_removed(tmp_path: Path) -> None:
    store_frames(tmp_path, [frame(0, "fish"), frame(1, "wreck"), frame(2, "fish")])
    pipe, removed = resumed(tmp_path, [FISH, CORAL])
    assert [(e.kind, e.frame.image_index, e.frame.topic) for e in removed] == [("removed", 1, "wreck")]
    assert [f.image_index for f in pipe.summary] == [0, 2]
