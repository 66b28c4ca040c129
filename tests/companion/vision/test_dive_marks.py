"""Dive-centred marks (companion.vision.feedback.CentredMarks) on synthetic features with a known object and scene.

A frame's features are its scene (a large offset shared by the frames of a stretch of the dive, changing every 15
frames) plus, when the object is in view, one fixed direction, plus noise; the query reads a coordinate that
says nothing about the object. The encoder is a stand-in whose embeddings are those features: the real encoders
cannot be told what the object is.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from companion.evaluation.feedback_eval import evaluate
from companion.evaluation.roc import auroc
from companion.vision.encoders.base import Encoder
from companion.vision.feedback import MarkedPreSampler, Marks
from companion.vision.presampler import PreSampler

DIM = 16


class FeatureEncoder(Encoder):
    """Embeddings are the features; the query's score is the sigmoid of coordinate 0."""

    name = "features"

    @property
    def input_size(self) -> tuple[int, int]:
        return (1, 1)

    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return np.stack([np.asarray(i, np.float32) for i in images])

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        return np.ones((len(texts), 1), np.float32)

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-image_embeddings[:, 0]))


def dive(seed: int, frames: int = 90) -> tuple[np.ndarray, np.ndarray]:
    """(frames, DIM) features and the object's presence, in the dive's order."""
    rng = np.random.default_rng(seed)
    obj = np.zeros(DIM)
    obj[1] = 1.0
    scene = np.repeat(rng.normal(0.0, 1.0, (frames // 15 + 1, DIM)), 15, axis=0)[:frames]
    scene[:, 0] = 0.0
    present = rng.random(frames) < 0.5
    present[:6] = [True, False, True, False, True, False]  # the first frames hold 3 + 3 marks
    x = scene + present[:, None] * obj * 2.0 + rng.normal(0.0, 0.3, (frames, DIM))
    return x.astype(np.float32), present


def test_marks_that_disagree_get_no_trust_and_change_nothing():
    encoder = FeatureEncoder()
    x, present = dive(0)
    base = PreSampler(encoder, "object", ["nothing"])
    base.scores(x[:30])  # the dive so far
    like = x[[0, 2]].astype(np.float64)
    unlike = like[::-1] + 0.01  # each "not this" sits on a "more like this"
    marked = MarkedPreSampler(base, Marks.from_features(like, unlike, like_pooled=like, unlike_pooled=unlike))
    assert marked.centred is not None and marked.centred_trust == 0.0 and marked.weight == 0.0
    assert np.array_equal(marked.scores(x[30:]), base.query_scores(x[30:]))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_consistent_marks_of_an_object_in_varying_scenes_lift_the_frames_not_marked(seed):
    encoder = FeatureEncoder()
    x, present = dive(seed)
    result = evaluate(encoder, PreSampler(encoder, "object", ["nothing"]), x, present, 3)
    assert result.centred_trust > 0.5
    assert result.auroc_query < 0.7 and result.auroc_marked > result.auroc_query + 0.2, result


def test_centred_marks_follow_the_dive_and_a_new_dive_starts_afresh():
    encoder = FeatureEncoder()
    x, present = dive(4)
    base = PreSampler(encoder, "object")
    marks = Marks.from_features(x[[0, 2, 4]], x[[1, 3, 5]], like_pooled=x[[0, 2, 4]], unlike_pooled=x[[1, 3, 5]])
    assert MarkedPreSampler(base, marks).centred is None  # given before any frame: nothing to centre them by
    base.scores(x[:6])
    marked = MarkedPreSampler(base, marks)
    assert marked.dive is base.dive and marked.centred_trust == 1.0
    marked.scores(x[6:40])
    rest = np.arange(40, len(x))
    assert auroc(marked.scores(x[rest]), present[rest]) > auroc(base.query_scores(x[rest]), present[rest]) + 0.2
    before = marked.dive.mean.copy()
    marked.scores(x[:4], join=False)  # a frame scored again does not move the dive's mean
    assert np.array_equal(marked.dive.mean, before)
    marked.new_dive()
    assert marked.dive.mean is None and marked.dive is not base.dive
