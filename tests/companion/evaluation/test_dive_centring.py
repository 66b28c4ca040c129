"""The dive's running mean (companion.evaluation.dive_centring): causal, graceful on a dive's first frames, and a
nested choice that never looks at the group it reports."""

from __future__ import annotations

import numpy as np
import pytest

from companion.evaluation.dive_centring import (
    RunningMean,
    centred,
    nested_centred_holdout,
    stream_order,
)
from companion.evaluation.roc import auroc
from companion.evaluation.sources import LabelledFrame

PIXEL = np.zeros((2, 2, 3), np.uint8)


def test_running_mean_starts_from_the_prior_and_is_causal():
    mean = RunningMean(prior=0.0, prior_weight=1.0, tau=100)
    assert mean.centre(4.0) == pytest.approx(2.0)  # first frame: half prior, half itself, never 0 by itself
    assert mean.centre(4.0) == pytest.approx(4.0 - 8.0 / 3.0)
    values = [1.0, 5.0, -2.0, 7.0]
    first = centred(np.array(values), [np.arange(4)], np.zeros(4), 1.0)
    later_changed = centred(np.array(values[:2] + [100.0, 100.0]), [np.arange(4)], np.zeros(4), 1.0)
    assert first[:2] == pytest.approx(later_changed[:2])  # a frame's value never depends on later frames


def test_running_mean_forgets_past_tau_frames():
    mean = RunningMean(prior=0.0, prior_weight=0.0, tau=10)
    for _ in range(200):
        mean.centre(0.0)
    for _ in range(50):
        mean.centre(1.0)
    assert mean.mean == pytest.approx(1.0 - 0.9 ** 50, abs=1e-9)  # exponential, not the mean of 250 frames
    with pytest.raises(ValueError):
        RunningMean(0.0, -1.0)


def test_running_mean_takes_feature_vectors():
    mean = RunningMean(prior=np.zeros(3), prior_weight=0.0)
    assert mean.centre(np.array([1.0, 2.0, 3.0])) == pytest.approx(np.zeros(3))
    assert mean.centre(np.array([3.0, 2.0, 1.0])) == pytest.approx(np.array([1.0, 0.0, -1.0]))


def test_no_prior_weight_means_no_centring():
    s = np.array([3.0, 1.0, 2.0])
    assert centred(s, [np.arange(3)], np.zeros(3), None) == pytest.approx(s)


def test_stream_order_shuffles_deepfish_habitats_only_and_keeps_each_stream_whole():
    frames = ([LabelledFrame("deepfish:1", f"d{i}", i < 5, PIXEL) for i in range(10)]
              + [LabelledFrame("rov_clips", f"r{i}", False, PIXEL) for i in range(4)])
    streams = stream_order(frames, seed=0)
    assert len(streams) == 2 and sorted(streams[0].tolist()) == list(range(10))
    assert streams[0].tolist() != list(range(10))  # the label-sorted file order is not the stream's order
    assert streams[1].tolist() == [10, 11, 12, 13]
    assert stream_order(frames, seed=0)[0].tolist() == streams[0].tolist()


def test_stream_order_by_clip_makes_each_clip_its_own_shuffled_dive():
    frames = ([LabelledFrame("deepfish:1", f"d{i}", i < 6, PIXEL, "F1" if i < 6 else "NF2") for i in range(14)]
              + [LabelledFrame("deepfish:2", f"e{i}", False, PIXEL, "NF1") for i in range(3)]
              + [LabelledFrame("rov_clips", f"r{i}", False, PIXEL) for i in range(4)])
    streams = stream_order(frames, seed=3, by_clip=True)
    assert [sorted(s.tolist()) for s in streams] == [list(range(6)), list(range(6, 14)), [14, 15, 16],
                                                     [17, 18, 19, 20]]
    assert streams[1].tolist() != list(range(6, 14)) and streams[3].tolist() == [17, 18, 19, 20]
    assert len(stream_order(frames, seed=3)) == 3  # by habitat: the two clips of habitat 1 are one dive


def _scenes(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Six groups whose scene shifts every feature (and so the score) by a large group offset."""
    rng = np.random.default_rng(seed)
    x, y, g = [], [], []
    for k in range(6):
        scene = rng.normal(0, 4, 10)
        for _ in range(40):
            label = bool(rng.random() < 0.5)
            x.append(scene + rng.normal(0, 1, 10) + (2.0 if label else 0.0) * np.eye(10)[0])
            y.append(label)
            g.append(f"g{k}")
    groups = np.array(g)
    return np.array(x), np.array(y), groups, [np.flatnonzero(groups == f"g{k}") for k in range(6)]


def test_nested_centring_lifts_the_pooled_auroc_when_scenes_shift_the_score():
    x, y, groups, streams = _scenes()
    plain, _ = nested_centred_holdout(x, y, groups, streams, lambdas=(10.0,), weights=(None,))
    dive, chosen = nested_centred_holdout(x, y, groups, streams, lambdas=(10.0,), weights=(None, 1.0, 5.0))
    assert auroc(dive, y) > auroc(plain, y) + 0.05
    assert set(chosen) == {f"g{k}" for k in range(6)} and all(w is not None for _, w in chosen.values())


def test_nested_centring_never_uses_the_held_out_group():
    x, y, groups, streams = _scenes()
    before, _ = nested_centred_holdout(x, y, groups, streams, lambdas=(10.0, 100.0))
    y2 = y.copy()
    y2[groups == "g0"] = ~y2[groups == "g0"]  # relabel the held-out group: its own scores must not move
    after, _ = nested_centred_holdout(x, y2, groups, streams, lambdas=(10.0, 100.0))
    assert before[groups == "g0"] == pytest.approx(after[groups == "g0"])
