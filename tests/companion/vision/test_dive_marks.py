"""Dive-centred marks (companion.vision.feedback.CentredMarks) on synthetic features with a known object and scene.

A frame's features are its scene (a large offset shared by the frames of a stretch of the dive, changing every 15
frames) plus, when the object is in view, one fixed direction, plus noise; the query reads a coordinate that
says nothing about the object. The encoder is a stand-in whose embeddings are those features: the real encoders
cannot be told what the object is.

Several topics share one dive: the pipeline's running mean, fed once per frame, must give every topic exactly the
scores a topic followed alone with its own running mean gave, computed here again in plain numpy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from companion.config import Config
from companion.evaluation.feedback_eval import evaluate
from companion.evaluation.roc import auroc
from companion.sources.frame import Frame
from companion.vision.encoders.base import Encoder
from companion.vision.feedback import CENTRED_WEIGHT, MarkedPreSampler, Marks
from companion.vision.pipeline import Pipeline
from companion.vision.presampler import PreSampler
from companion.vision.topics import TopicSpec

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
    # at CENTRED_WEIGHT 1, times the query's doubt (it sorts a few of the marks' pairs by chance): +0.10 to +0.26
    # (+0.18 to +0.36 at 2)
    assert result.auroc_query < 0.7 and result.auroc_marked > result.auroc_query + 0.08, result


@pytest.mark.parametrize(("order", "doubt"), [("right", 0.0), ("backwards", 1.0), ("mixed", 2 / 3)])
def test_centred_marks_weigh_as_far_as_the_query_fails_to_sort_them(order, doubt):
    encoder = FeatureEncoder()
    x, present = dive(1)
    base = PreSampler(encoder, "object")
    base.scores(x[:30])
    like, unlike = x[[0, 2, 4]].astype(np.float64), x[[1, 3, 5]].astype(np.float64)
    query = {"right": ([0.9, 0.8, 0.7], [0.3, 0.2, 0.1]), "backwards": ([0.1, 0.2, 0.3], [0.7, 0.8, 0.9]),
             "mixed": ([0.9, 0.5, 0.2], [0.6, 0.4, 0.1])}[order]  # mixed: 6 of 9 pairs right, 2 * 6/9 - 1 sure
    marks = Marks.from_features(like, unlike, *query, like_pooled=like, unlike_pooled=unlike)
    marked = MarkedPreSampler(base, marks)
    assert marked.centred_trust == 1.0 and marked.centred.doubt == pytest.approx(doubt)
    alone = base.query_scores(x[30:])
    if doubt == 0.0:  # the query already sorts the marks: they add nothing it does not know
        assert np.array_equal(marked.scores(x[30:]), alone)
    else:
        rest = np.arange(30, len(x))
        assert auroc(marked.scores(x[rest]), present[rest]) > auroc(alone, present[rest]) + 0.1


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


class TopicEncoder(FeatureEncoder):
    """A query "coordinate K" scores the sigmoid of coordinate K; counts the pooled-feature requests."""

    def __init__(self) -> None:
        self.pooled_calls = 0

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = np.zeros((len(texts), DIM), np.float32)
        for row, text in zip(out, texts, strict=True):
            if text.startswith("coordinate "):
                row[int(text.split()[1])] = 1.0
        return out

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-image_embeddings[:, int(np.argmax(text_embeddings[0]))]))

    def sampler_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        self.pooled_calls += 1
        return image_embeddings


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


def alone_with_its_own_mean(x, query, like, unlike, batches, marks_after, tau=100,
                            weight=CENTRED_WEIGHT) -> np.ndarray:
    """One topic's scores as its own pre-sampler gave them: its running mean of ``x`` (rate max(1/n, 1/tau)),
    3 + 3 centred marks set after ``marks_after`` frames, each batch lifted by its centred features along the
    marks' direction, scaled by the last ``tau`` frames' spreads (docs/encoders.md)."""
    mean, n, recent_c, recent_q, out, marks = np.zeros(DIM), 0, [], [], [], None
    start = 0
    for size in batches:
        if start == marks_after:
            lk, ulk = x[like].astype(np.float64) - mean, x[unlike].astype(np.float64) - mean
            checks = [(lk[i] - (np.delete(lk, i, 0).mean(0) + ulk.mean(0)) / 2) @ (np.delete(lk, i, 0).mean(0) - ulk.mean(0))
                      for i in range(len(lk))]
            checks += [(ulk[i] - (np.delete(ulk, i, 0).mean(0) + lk.mean(0)) / 2) @ (np.delete(ulk, i, 0).mean(0) - lk.mean(0))
                       for i in range(len(ulk))]
            trust = max(0.0, 2.0 * np.mean(np.array(checks) > 0) - 1.0)
            direction = lk.mean(0) - ulk.mean(0)
            pairs = query[like][:, None] - query[unlike][None, :]
            doubt = 1.0 - max(0.0, 2.0 * np.mean((pairs > 0) + 0.5 * (pairs == 0)) - 1.0)
            marks = (direction, trust * doubt, np.concatenate([lk, ulk]) @ direction,
                     _logit(np.concatenate([query[like], query[unlike]])))
        centred = []
        for i in range(start, start + size):
            n += 1
            mean = mean + max(1.0 / n, 1.0 / tau) * (x[i].astype(np.float64) - mean)
            centred.append(x[i] - mean)
            recent_c, recent_q = [*recent_c, centred[-1]][-tau:], [*recent_q, _logit(query[i])][-tau:]
        score = query[start:start + size].astype(np.float64)
        if marks is not None and marks[1] > 0:
            direction, trust, along_marks, logits_marks = marks
            along = np.concatenate([np.array(recent_c) @ direction, along_marks])
            spread_q = np.std(np.concatenate([np.array(recent_q), logits_marks]))
            lift = weight * trust * spread_q * (np.array(centred) @ direction - along.mean()) / np.std(along)
            score = 1.0 / (1.0 + np.exp(-(_logit(score) + lift)))
        out.append(score.astype(np.float32))
        start += size
    return np.concatenate(out)


@pytest.mark.parametrize("coordinates", [(0,), (0, 2, 3)])
def test_topics_share_one_dive_and_score_as_each_did_with_its_own(coordinates):
    encoder = TopicEncoder()
    x, _present = dive(5)
    like, unlike = [0, 2, 4], [1, 3, 5]
    cfg = Config.model_validate({"gate": {"mode": "none"}, "queries": {"tau_ss": 0.5, "topics": [
        {"name": f"c{k}", "positive": f"coordinate {k}"} for k in coordinates]}})
    pipe = Pipeline.from_config(cfg, encoder)
    batches, start, got = [8, 8, 5, *[8] * 8, 5], 0, []
    for size in batches:
        if start == 16:  # the operator marks the first 3 + 3 frames, each topic with its own query's scores
            for topic in pipe.topics:
                q = topic.presampler.query_scores(x)
                marks = Marks.from_features(x[like], x[unlike], q[like], q[unlike],
                                            like_pooled=x[like], unlike_pooled=x[unlike])
                topic.presampler = MarkedPreSampler(topic.presampler, marks)
                assert topic.presampler.centred_trust > 0.5
        frames = [Frame(np.zeros((2, 2, 3), np.uint8), i, i / 5.0, 0.0) for i in range(start, start + size)]
        got.append([[r.topic_scores[t.name] for t in pipe.topics]
                    for r in pipe.process(frames, prepared=list(x[start:start + size])).results])
        start += size
    got = np.concatenate(got)
    assert start == len(x)

    assert pipe.dive.frames == len(x)  # one dive, fed once per frame, whatever the number of topics
    assert all(t.presampler.dive is pipe.dive for t in pipe.topics)
    assert encoder.pooled_calls == len(batches)  # the pooled features asked for once per encoder pass
    for column, k in enumerate(coordinates):
        query = (1.0 / (1.0 + np.exp(-x[:, k]))).astype(np.float32)
        want = alone_with_its_own_mean(x, query, like, unlike, batches, 16)
        assert not np.allclose(want[16:], query[16:], atol=1e-3)  # the marks move the scores: the case is real
        np.testing.assert_allclose(got[:, column], want, rtol=1e-6, atol=1e-7)

    pipe.set_topics([TopicSpec("c0", "coordinate 0"), TopicSpec("new", "coordinate 4")])
    assert all(t.presampler.dive is pipe.dive for t in pipe.topics)  # a topic followed later reads the same dive
