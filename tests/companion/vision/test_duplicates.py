"""A summary never holds the same picture twice (issue 25 item 2): real videos written with OpenCV, the packaged
encoder, the whole summarize path with the frame gate on and off, and a looping clip as the live camera loops it."""

from __future__ import annotations

import itertools
import json
import math

import cv2
import numpy as np
import pytest

from companion.config import load_config
from companion.sources.factory import open_source
from companion.vision import distances as dist
from companion.vision.encoders.factory import make_encoder
from companion.vision.pipeline import Pipeline
from companion.vision.sampler import DUPLICATE_COSINE, InformativeSampler
from companion.vision.summarize import summarize
from tests.conftest import shared_file

STILLS = ["suim/images/f_r_1965_.jpg", "suim/images/d_r_47_.jpg", "aquarium_fish/frames/000001.jpg"]
LOOP = [f"aquarium_fish/frames/{n:06d}.jpg" for n in (1, 11, 21, 31, 41)]


def write_video(path, images, fps: float, size=(640, 480)) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert writer.isOpened()
    for image in images:
        writer.write(cv2.resize(image, size))
    writer.release()


@pytest.fixture(scope="module")
def encoder():
    return make_encoder(load_config(None, overrides={"encoder": {"name": "imagenet"}}).encoder)


@pytest.fixture(scope="module")
def three_stills(tmp_path_factory):
    """Three different stills, each held 2 s at 10 fps (60 frames)."""
    path = tmp_path_factory.mktemp("stills") / "three_stills.mp4"
    stills = [cv2.imread(str(shared_file(name))) for name in STILLS]
    write_video(path, [still for still in stills for _ in range(20)], 10.0)
    return path


def at(deg: float) -> np.ndarray:
    """A unit vector in the positive quadrant: the cosine distance of two is 1 - cos(their angle)."""
    r = math.radians(deg)
    return np.array([math.cos(r), math.sin(r), 0.0])


def test_a_frame_equal_to_a_member_never_enters_not_even_in_warm_up():
    sampler = InformativeSampler(k=6)
    assert sampler.offer(0, at(0)).added
    same = sampler.offer(1, at(0) * 3.0)  # the same direction: the same picture once normalised
    assert (same.added, same.duplicate, same.warmup) == (False, True, True)
    assert 1 - math.cos(math.radians(3)) < DUPLICATE_COSINE < 1 - math.cos(math.radians(10))
    assert sampler.offer(2, at(45)).added
    assert sampler.offer(3, at(48)).duplicate  # 3 degrees from a member: nearly equal
    assert sampler.offer(4, at(55)).added  # 10 degrees from every member: a different picture
    assert sampler.keys == [0, 2, 4]


@pytest.mark.parametrize("gate", ["difference", "none"])
def test_three_stills_give_three_frames_and_say_the_summary_is_short(three_stills, encoder, tmp_path, gate):
    cfg = load_config(None, overrides={"source": {"uri": str(three_stills), "fps": 10.0},
                                       "queries": {"tau_ss": 0.0}, "sampler": {"k": 6},
                                       "gate": {"mode": gate}})
    run = summarize(cfg, tmp_path / "out", encoder=encoder)
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    indices = [f["index"] for f in doc["frames"]]
    assert len(indices) == 3 and sorted(i // 20 for i in indices) == [0, 1, 2], indices
    assert run.frames_seen == 60 and doc["params"]["stats"]["frames_duplicate"] >= (0 if gate == "difference" else 50)
    assert doc["params"]["short"] == ["main: 3 of K=6 frames, the video has no more distinct views that passed "
                                      "the query"]
    assert len(list((tmp_path / "out" / "frames").iterdir())) == 3


def test_a_looping_clip_holds_each_view_once(tmp_path, encoder):
    """A 0.5 s clip of five different views looped by the source (as the live camera loops a file): the summary
    holds the five views once each, none byte-identical or feature-identical to another."""
    path = tmp_path / "loop.mp4"
    write_video(path, [cv2.imread(str(shared_file(name))) for name in LOOP], 10.0)
    cfg = load_config(None, overrides={"source": {"uri": str(path), "fps": 10.0, "loop": True, "realtime": False},
                                       "queries": {"tau_ss": 0.0}, "sampler": {"k": 6}, "gate": {"mode": "none"}})
    pipe = Pipeline.from_config(cfg, encoder)
    source = open_source(cfg.source)
    try:
        frames = list(itertools.islice(iter(source), 40))  # eight times round the loop
    finally:
        source.close()
    for start in range(0, len(frames), 8):
        pipe.process(frames[start:start + 8])
    held = pipe.summary
    assert len(held) == 5 and sorted(f.frame_index % 5 for f in held) == [0, 1, 2, 3, 4]
    for a, b in itertools.combinations(held, 2):
        assert not np.array_equal(a.image, b.image)
        assert float(dist.cosine_many(a.feature, b.feature[None, :])[0]) > DUPLICATE_COSINE
    assert pipe.counts["duplicates"] == 35
