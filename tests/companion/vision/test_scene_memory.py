"""The dive's scene memory and the scene head: causal residuals, and the pre-sampler scoring a dive with them."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.vision.dive_mean import TAU
from companion.vision.encoders.imagenet import FEATURES, ImageNetEncoder
from companion.vision.pixel_scene import PixelScene
from companion.vision.presampler import PreSampler
from companion.vision.scene_memory import SceneInput, SceneMemory
from tests.conftest import run_merlion


def _reference(views: np.ndarray, tau: float = TAU) -> np.ndarray:
    """Written out independently: the mean of frames 0..t-1 (exponential with rate 1/tau once t >= tau), and
    mean over views of max(view_t - that mean, 0); NaN for frame 0."""
    out = np.full((len(views), views.shape[2]), np.nan)
    mean = views[0].astype(np.float64)
    for t in range(1, len(views)):
        out[t] = np.clip(views[t] - mean, 0, None).mean(axis=0)  # against the frames before it
        rate = max(1.0 / (t + 1), 1.0 / tau)
        mean = mean + rate * (views[t] - mean)
    return out


def test_a_frame_is_compared_with_the_dive_before_it_not_with_itself():
    """At a dive's second frame a mean that held the frame would halve its change."""
    views = np.zeros((2, 1, 4))
    views[1, 0] = [2.0, 0.0, -2.0, 4.0]
    got = SceneMemory().residuals(_inputs(views, 0))
    np.testing.assert_allclose(got[1, :4], [2.0, 0.0, 0.0, 4.0])


def _inputs(views: np.ndarray, seed: int) -> SceneInput:
    """Views with small frames of a still scene beside them."""
    rng = np.random.default_rng(seed)
    pixels = np.clip(0.4 + rng.normal(0, 0.05, size=(len(views), 64, 112, 3)), 0, 1)
    return SceneInput(views, pixels)


def test_residuals_are_the_causal_positive_difference_from_the_dive_mean_then_the_pixel_changes():
    rng = np.random.default_rng(0)
    views = rng.normal(size=(40, 3, 16))
    scene = _inputs(views, 0)
    got = SceneMemory(tau=10).residuals(scene)
    want = np.concatenate([_reference(views, tau=10), PixelScene(tau=10).features(scene.pixels)], axis=1)
    assert got.shape == (40, 16 + 12) and scene.width == 28
    assert np.isnan(got[0]).all() and np.isfinite(got[1:]).all()
    np.testing.assert_allclose(got[1:], want[1:], rtol=1e-12, atol=1e-12)
    assert (got[1:, :16] >= 0).all()
    memory = SceneMemory(tau=10)  # batches of any size give the same residuals
    parts = [memory.residuals(scene[i:i + k]) for i, k in ((0, 1), (1, 7), (8, 32))]
    np.testing.assert_allclose(np.concatenate(parts)[1:], want[1:], rtol=1e-12, atol=1e-12)


def test_a_frame_scored_again_does_not_join_the_scene():
    rng = np.random.default_rng(1)
    views = rng.normal(size=(6, 2, 8))
    scene = _inputs(views, 1)
    memory = SceneMemory()
    assert np.isnan(memory.residuals(scene[:1], join=False)).all() and not memory.seen  # no dive yet
    memory.residuals(scene[:3])
    bright = np.clip(scene.pixels[3:5] * 1.5, 0, 1)
    again = memory.residuals(SceneInput(views[3:5] * 2.0, bright), join=False)  # e.g. enhanced copies
    mean = views[:3].mean(axis=0)
    np.testing.assert_allclose(again[:, :8], np.clip(views[3:5] * 2.0 - mean, 0, None).mean(axis=1), atol=1e-12)
    pixels = PixelScene()  # the pixel part: the same copies, against the same three frames, not joined
    pixels.features(scene.pixels[:3])
    np.testing.assert_allclose(again[:, 8:], pixels.features(bright, join=False), atol=1e-12)
    # neither part took the copies in: the dive goes on as if they had never been scored
    want = np.concatenate([_reference(views), PixelScene().features(scene.pixels)], axis=1)
    np.testing.assert_allclose(memory.residuals(scene[3:]), want[3:], atol=1e-12)
    with pytest.raises(ValueError, match="views must be"):
        SceneInput(views[0], scene.pixels[0])
    with pytest.raises(ValueError, match="6 frames of views but 5 of pixels"):
        SceneInput(views, scene.pixels[:5])
    assert scene[-1].views.shape == (1, 2, 8) and np.array_equal(scene[-1].pixels[0], scene.pixels[5])
    assert len(scene[np.array([True, False] * 3)]) == 3 and len(scene[[0, 2]]) == 2 and len(scene[2:]) == 4
    with pytest.raises(IndexError):
        scene[6]


def _scene_reference(encoder: ImageNetEncoder, emb: np.ndarray) -> np.ndarray:
    """The views' residual (written out above) and the pixel changes (``test_pixel_scene``) of one dive."""
    scene = encoder.scene_of(emb)
    return np.concatenate([_reference(scene.views.astype(np.float64)), PixelScene().features(scene.pixels)], axis=1)


@pytest.fixture(scope="module")
def dive():
    """The packaged encoder (with its shipped heads) and a short 'dive': one scene, a bright object coming and
    going in one corner."""
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"))
    rng = np.random.default_rng(2)
    scene = rng.integers(40, 120, size=(256, 448, 3), dtype=np.uint8)
    frames = []
    for t in range(8):
        f = np.clip(scene.astype(int) + rng.integers(-6, 7, size=scene.shape), 0, 255).astype(np.uint8)
        if t % 3 == 2:
            f[20:110, 300:420] = (230, 210, 90)
        frames.append(f)
    return encoder, encoder.encode_images(frames), frames


def test_presampler_scores_a_dive_by_the_scene_head_after_its_first_frame(dive):
    encoder, emb, _ = dive
    pooled_head = next(h for h in encoder.heads if h.input == "pooled")
    scene_head = next(h for h in encoder.heads if h.input == "scene")
    presampler = PreSampler(encoder, "fish")
    scores = np.concatenate([presampler.scores(emb[:3]), presampler.scores(emb[3:])])
    residual = _scene_reference(encoder, emb)
    # the first frame has no scene before it: the pooled head answers; then the scene head on the residual
    assert scores[0] == pytest.approx(pooled_head.probabilities(emb[:1, :FEATURES])[0], abs=1e-6)
    np.testing.assert_allclose(scores[1:], scene_head.probabilities(residual[1:]), atol=1e-6)
    assert len(set(np.round(scores[1:], 6))) > 1  # the frames are told apart
    # scoring copies again does not move the scene; a new dive starts from nothing
    presampler.query_scores(emb[::-1])
    presampler.new_dive()
    assert presampler.scores(emb[:1])[0] == pytest.approx(scores[0], abs=1e-6)
    np.testing.assert_allclose(presampler.scores(emb[1:]), scores[1:], atol=1e-6)


def test_an_encoder_without_a_scene_head_scores_as_before(dive):
    encoder, emb, _ = dive
    plain = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"), heads=False)
    assert plain.scene_input(emb) is None
    presampler = PreSampler(plain, "fish")
    np.testing.assert_allclose(presampler.scores(emb), plain.semantic_scores(emb, presampler.text_embeddings))
    assert not presampler.dive.scene.seen


def test_score_judges_images_on_their_own_unless_they_are_one_dive(dive, tmp_path):
    encoder, emb, frames = dive
    for i, f in enumerate(frames[:5]):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), f)
    alone = run_merlion("score", str(tmp_path), "--query", "fish", "--encoder", "imagenet", "--json")
    as_dive = run_merlion("score", str(tmp_path), "--query", "fish", "--encoder", "imagenet", "--json", "--dive")
    assert alone.returncode == 0 and as_dive.returncode == 0, (alone.stderr, as_dive.stderr)
    a = [json.loads(line)["score"] for line in alone.stdout.splitlines()]
    d = [json.loads(line)["score"] for line in as_dive.stdout.splitlines()]
    pooled = next(h for h in encoder.heads if h.input == "pooled").probabilities(emb[:5, :FEATURES])
    scene = next(h for h in encoder.heads if h.input == "scene")
    np.testing.assert_allclose(a, pooled, atol=2e-3)  # PNG round trip: same pixels
    assert d[0] == pytest.approx(a[0], abs=1e-6)
    np.testing.assert_allclose(d[1:], scene.probabilities(_scene_reference(encoder, emb[:5])[1:]), atol=2e-3)
