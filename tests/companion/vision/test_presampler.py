"""Semantic pre-sampling: REFERENCE.md's ss_t, the strict threshold, percentages, the generic negative."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.errors import MerlionError, UsageError
from companion.sources.video import VideoSource
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.presampler import GENERIC_NEGATIVE, PreSampler, softmax_share
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def encoder():
    return ImageNetEncoder(EncoderConfig(name="imagenet"), regions=False)


def test_softmax_share_is_the_positive_share_at_scale_100():
    v = np.array([[1.0, 0.0], [0.6, 0.8], [0.0, 2.0]])
    q = np.array([[1.0, 0.0], [0.0, 3.0]])  # not normalised: ss_t must normalise both sides
    cos = np.array([[1.0, 0.0], [0.6, 0.8], [0.0, 1.0]])
    want = np.exp(100 * cos[:, 0]) / np.exp(100 * cos).sum(axis=1)
    assert np.allclose(softmax_share(v, q), want, atol=1e-7)
    assert softmax_share(v, q)[1] == pytest.approx(1 / (1 + np.exp(20.0)), rel=1e-5)


def test_scores_are_the_encoders_share_and_pass_strictly(encoder):
    frames = list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=1))
    emb = encoder.encode_images([f.image for f in frames])
    pre = PreSampler(encoder, "underwater image with fish", ["underwater image without fish"], tau_ss=0.5)
    scores = pre.scores(emb)
    assert scores.shape == (len(frames),) and np.all((scores >= 0) & (scores <= 1))
    assert np.allclose(scores, encoder.semantic_scores(emb, encoder.encode_texts(pre.queries)))
    assert scores.min() < 0.5 < scores.max()  # the survey has fish and no-fish segments
    assert list(pre.passes(scores)) == [s > 0.5 for s in scores]
    assert not pre.passes(np.array([0.5]))[0]  # strict
    assert pre.passes(np.array([0.5]), tau=0.4)[0]


def test_tau_accepts_a_percentage_and_refuses_nonsense(encoder):
    pre = PreSampler(encoder, "fish", tau_ss=40)
    assert pre.tau_ss == pytest.approx(0.4)
    pre.tau_ss = 0.7
    assert pre.tau_ss == 0.7
    with pytest.raises(UsageError, match="tau_ss"):
        pre.tau_ss = -0.1
    with pytest.raises(UsageError, match="tau_ss"):
        pre.tau_ss = 150


def test_tau_zero_is_no_semantic_gate(encoder):
    pre = PreSampler(encoder, "fish", tau_ss=0)
    assert pre.tau_ss == 0.0
    assert pre.passes(np.array([0.0, 1e-30, 0.5, 0.99])).all()  # a share that underflowed to 0 still passes
    pre.tau_ss = 0.3
    assert pre.passes(np.array([0.0, 0.3, 0.31])).tolist() == [False, False, True]


def test_no_negative_uses_the_generic_one_or_the_positive_alone(encoder):
    pre = PreSampler(encoder, "underwater image with fish")
    # the imagenet encoder cannot embed the generic phrase, so it scores the positive concept's mass alone
    with pytest.raises(MerlionError):
        encoder.encode_texts([GENERIC_NEGATIVE])
    assert pre.queries == ["underwater image with fish"]
    pre.set_queries("underwater image with fish", ["underwater image without fish"])
    assert pre.queries == ["underwater image with fish", "underwater image without fish"]


def test_unknown_positive_is_a_one_line_error(encoder):
    with pytest.raises(MerlionError) as err:
        PreSampler(encoder, "a red blorptang")
    assert "blorptang" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(UsageError):
        PreSampler(encoder, "   ")


@pytest.fixture(scope="module")
def clip_encoder(tmp_path_factory):
    """A real open_clip architecture (ViT-S-32) with random weights, saved and loaded through the weights path."""
    open_clip = pytest.importorskip("open_clip")
    import torch

    from companion.vision.encoders.factory import make_encoder

    torch.manual_seed(0)
    model = open_clip.create_model("ViT-S-32", pretrained=None)
    path = tmp_path_factory.mktemp("clip") / "vit-s-32-random.pt"
    torch.save(model.state_dict(), path)
    del model
    return make_encoder(EncoderConfig(name="clip", model="ViT-S-32", weights=str(path), precision="fp32"))


def test_clip_ss_t_is_the_softmax_share_with_the_generic_negative(clip_encoder):
    pre = PreSampler(clip_encoder, "underwater image with fish", tau_ss=0.5)
    assert pre.queries == ["underwater image with fish", GENERIC_NEGATIVE]
    frames = list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=1))[:4]
    emb = clip_encoder.encode_images([f.image for f in frames])
    want = softmax_share(emb, clip_encoder.encode_texts(pre.queries))
    assert np.allclose(pre.scores(emb), want, atol=1e-5)
