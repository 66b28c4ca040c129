"""The ROST-style visual baseline encoder on real survey frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.vision import distances
from companion.vision.encoders.visual import VisualEncoder, lbp_histogram
from companion.vision.sampler import InformativeSampler
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def survey() -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(shared_file("survey/survey_480x270.mp4")))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    assert len(frames) == 93
    return frames


@pytest.fixture(scope="module")
def embeddings(survey) -> np.ndarray:
    return VisualEncoder().encode_images(survey)


SEGMENT = np.array([0] * 11 + [1] * 30 + [2] * 11 + [3] * 30 + [4] * 11)


def test_features_are_distributions_and_deterministic(survey, embeddings):
    enc = VisualEncoder()
    assert embeddings.shape == (93, enc.dim) and embeddings.dtype == np.float32
    assert np.all(embeddings >= 0)
    np.testing.assert_allclose(embeddings.sum(axis=1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(VisualEncoder().encode_images(survey[:3]), embeddings[:3])
    assert enc.encode_images([]).shape == (0, enc.dim)


def test_no_semantics_every_frame_passes(embeddings):
    enc = VisualEncoder()
    text = enc.encode_texts(["underwater image with fish", "underwater image without fish"])
    assert text.shape == (2, 1)
    scores = enc.semantic_scores(embeddings, text)
    assert scores.shape == (93,) and np.all(scores == 1.0)
    assert "none" in enc.describe()["semantic"]


def test_featureless_frame_and_input_size():
    enc = VisualEncoder(EncoderConfig(name="visual", input_size=160))
    assert enc.input_size == (160, 90)
    grey = np.full((90, 160, 3), 128, np.uint8)
    v = enc.encode_images([grey])[0]
    assert np.isfinite(v).all() and v.sum() == pytest.approx(1.0, rel=1e-5)


def test_lbp_of_a_flat_image_is_one_pattern():
    hist = lbp_histogram(np.full((10, 10), 7, np.uint8))
    assert hist.max() == 1.0 and hist.sum() == pytest.approx(1.0)


def test_frames_of_one_segment_are_closer_than_frames_of_different_segments(embeddings):
    d = distances.pairwise(distances.prepare_features(embeddings.astype(np.float64)), "js")
    same = SEGMENT[:, None] == SEGMENT[None, :]
    assert d[same].mean() * 3 < d[~same].mean()


def test_sampler_on_visual_features_spreads_over_the_survey(embeddings):
    sampler = InformativeSampler(k=6)
    for i, v in enumerate(VisualEncoder().sampler_features(embeddings)):
        sampler.offer(i, v)
    segments = {int(SEGMENT[k]) for k in sampler.keys}
    assert len(sampler.keys) == 6 and len(segments) >= 3
