"""Learned heads (companion.vision.encoders.learned_head): when one answers a query, the file format, the shipped one."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.errors import MerlionError
from companion.vision.encoders.imagenet import FEATURES, SCENE, ImageNetEncoder
from companion.vision.encoders.learned_head import HEADS_DIR, SURE, LinearHead, head_for, load_head


def _head(classes=(1, 2, 3, 4)) -> LinearHead:
    return LinearHead("fish", tuple(classes), "lite0", "none", np.array([1.0, -2.0, 0.5]), 0.25, {"lambda": 10.0})


def _mask(classes) -> np.ndarray:
    m = np.zeros(1000)
    m[list(classes)] = 1.0
    return m


def test_a_head_answers_a_query_whose_classes_are_nearly_its_own():
    head = _head()
    assert head.matches(_mask([1, 2, 3, 4])) and head.matches(_mask([1, 2, 3, 4, 5]))
    assert not head.matches(_mask([1])) and not head.matches(_mask([7, 8])) and not head.matches(np.zeros(1000))
    assert head_for([head], _mask([1, 2, 3])) is head and head_for([head], _mask([9])) is None


def test_probability_is_the_sigmoid_of_the_linear_score_kept_below_certainty():
    head = _head()
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 2.0], [100.0, 0.0, 0.0], [-100.0, 0.0, 0.0]])
    assert np.allclose(head.logits(x), [0.25, 2.25, 100.25, -99.75])
    sigmoid = 1 / (1 + np.exp(-head.logits(x)))
    p = head.probabilities(x)
    assert np.allclose(p, (1 - SURE) + (2 * SURE - 1) * sigmoid)
    assert np.all(np.diff(p[[3, 0, 1, 2]]) > 0)  # the same order as the sigmoid
    # however sure the features look, the top of tau_ss's range (0.998 and up) still passes nothing
    assert np.float32(p[2]) <= SURE and np.float32(p[3]) >= 1 - SURE


def test_a_head_survives_its_file(tmp_path):
    head = _head()
    back = load_head(head.save(tmp_path / "h.json"))
    assert (back.concept, back.classes, back.backbone, back.colour, back.b) == ("fish", (1, 2, 3, 4), "lite0", "none", 0.25)
    assert np.allclose(back.w, head.w) and back.trained_on == {"lambda": 10.0}
    bad = tmp_path / "bad.json"
    bad.write_text('{"concept": "fish"}')
    with pytest.raises(MerlionError, match=f"{bad}: not a readable learned head"):
        load_head(bad)


def test_the_shipped_fish_head_is_small_answers_fish_and_not_other_concepts():
    path = HEADS_DIR / "fish.json"
    assert path.stat().st_size < 40_000
    head = load_head(path)
    assert head.w.shape == (FEATURES,) and head.trained_on["frames"] > 700
    assert head.trained_on["sources"]["suim"] == 8 and sum(k.startswith("deepfish:") for k in head.trained_on["sources"]) == 10
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"))
    assert [(h.concept, h.input) for h in encoder.heads] == [("fish", "pooled"), ("fish", "scene")]
    assert encoder.describe()["heads"] == ["fish", "fish (scene)"]
    assert encoder.head_of(encoder.encode_texts(["fish"])) is not None
    for kind in ("flatfish", "seahorse", "grouper"):  # kinds of fish the model has no class of: the head answers
        assert encoder.head_of(encoder.encode_texts([kind])) is not None, kind
    assert encoder.head_of(encoder.encode_texts(["coral"])) is None
    assert encoder.scene_head_of(encoder.encode_texts(["flatfish"])) is encoder.heads[1]  # its scene partner
    assert encoder.scene_head_of(encoder.encode_texts(["coral"])) is None
    assert ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"), colour="grayworld").heads == []


def test_fish_query_is_scored_by_the_head_and_marks_use_the_most_fish_like_region():
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"))
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (202, 360, 3), dtype=np.uint8) for _ in range(2)]
    emb = encoder.encode_images(frames)
    # pooled, classes of each view, the regions' features, the small frame (112 x 64 x 3), the scene slot
    assert emb.shape == (2, FEATURES + encoder.views * 1000 + (encoder.views - 1) * FEATURES + 112 * 64 * 3 + SCENE)
    text = encoder.encode_texts(["fish"])
    head = encoder.heads[0]  # outside a dive (scene slot NaN) the pooled head answers
    assert np.allclose(encoder.semantic_scores(emb, text), head.probabilities(emb[:, :FEATURES]), atol=1e-6)
    views = encoder.view_features(emb)
    assert views.shape == (2, encoder.views, FEATURES) and np.allclose(views[:, 0], emb[:, :FEATURES])
    best = np.argmax(head.logits(views.reshape(-1, FEATURES)).reshape(2, -1), axis=1)
    assert np.allclose(encoder.object_features(emb, text), views[np.arange(2), best])
