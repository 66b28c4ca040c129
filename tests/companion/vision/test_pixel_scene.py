"""The dive's small-frame background and each frame's change features against it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.vision.pixel_scene import FEATURES, SIZE, PixelScene, small_frame

H, W = SIZE[1], SIZE[0]


def _still_scene(frames: int, seed: int = 0) -> np.ndarray:
    """A fixed camera: one textured scene with a little sensor noise per frame, (frames, 64, 112, 3) in [0, 1]."""
    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.uniform(0.2, 0.6, size=(H, W, 3)), (0, 0), 2.0)
    return np.clip(scene + rng.normal(0, 0.01, size=(frames, H, W, 3)), 0, 1)


def _reference(pixels: np.ndarray, tau: float, copies: np.ndarray | None = None) -> np.ndarray:
    """Written out independently: blurred frames; each against the mean of frames 0..t-1, then the mean of the
    squared change of frames 1..t (rate 1/(t+1), then 1/tau); the six measures on |change| summed over colours
    and on it over the spread. With ``copies``: their rows instead, each against the mean and spread after the last frame, neither taken in."""
    def six(c: np.ndarray) -> list[float]:
        def blob(k: int) -> float:
            return float((cv2.blur(c, (k, k)) - cv2.blur(c, (5 * k, 5 * k))).max())
        return [float(c.max()), float(np.quantile(c, 0.99)), float(c.mean()), blob(3), blob(5), blob(9)]

    def row(diff: np.ndarray, square: np.ndarray) -> np.ndarray:
        change = np.abs(diff).sum(axis=2).astype(np.float32)
        spread = square.sum(axis=2)
        scaled = (change / np.sqrt(spread + max(spread.mean(), 1e-4))).astype(np.float32)  # the floor: still scene
        return np.log1p(10.0 * np.array(six(change) + six(scaled)))

    def blurred(p: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(p.astype(np.float64), (0, 0), 0.7)

    out = np.full((len(pixels), 12), np.nan)
    x = [blurred(p) for p in pixels]
    mean, square = x[0], np.zeros_like(x[0])
    for t in range(1, len(x)):
        rate = max(1.0 / (t + 1), 1.0 / tau)
        diff = x[t] - mean  # against the frames before it
        mean = mean + rate * (x[t] - mean)
        square = square + rate * (diff ** 2 - square)
        out[t] = row(diff, square)
    if copies is None:
        return out
    return np.array([row(blurred(c) - mean, square) for c in copies])


def test_features_are_the_change_against_the_causal_background_in_any_batches():
    pixels = _still_scene(30)
    pixels[12:18] += np.random.default_rng(1).normal(0, 0.05, size=(6, H, W, 3))  # a noisy stretch
    want = _reference(pixels, tau=8)
    got = PixelScene(tau=8).features(pixels)
    assert got.shape == (30, FEATURES) and np.isnan(got[0]).all() and np.isfinite(got[1:]).all()
    np.testing.assert_allclose(got[1:], want[1:], rtol=1e-5, atol=1e-5)
    memory = PixelScene(tau=8)
    parts = [memory.features(pixels[i:i + k]) for i, k in ((0, 1), (1, 9), (10, 20))]
    np.testing.assert_allclose(np.concatenate(parts)[1:], want[1:], rtol=1e-5, atol=1e-5)


def test_a_small_fish_stands_out_and_a_whole_frame_change_less_so():
    pixels = _still_scene(40, seed=2)
    spot, shift = 25, 32
    pixels[spot, 30:34, 60:65] += 0.25  # a fish 4 pixels wide: 13 in a 360-pixel frame
    pixels[shift] = np.clip(pixels[shift] * 1.08, 0, 1)  # the light brightens over the whole frame
    got = PixelScene().features(pixels)
    quiet = np.delete(np.arange(5, 40), [spot - 5, shift - 5])
    blobs = [3, 4, 5, 9, 10, 11]  # the compact-change measures, plain and over the spread
    assert (got[spot, blobs] > got[quiet][:, blobs].max(axis=0)).all()
    assert got[spot, 3:6].max() > got[shift, 3:6].max()  # compact beats spread out, though the shift moved more
    assert got[shift, 2] > got[spot, 2]  # mean change: the shift moved more pixels


def test_a_frame_scored_again_does_not_join_the_background():
    pixels = _still_scene(12, seed=3)
    memory = PixelScene()
    assert np.isnan(memory.features(pixels[:1], join=False)).all() and not memory.seen  # no dive yet
    memory.features(pixels[:6])
    bright = np.clip(pixels[6:8] * 1.5, 0, 1)
    again = memory.features(bright, join=False)  # e.g. enhanced copies
    # each copy against the mean and spread of frames 0..5, as they stood
    np.testing.assert_allclose(again, _reference(pixels[:6], 100.0, copies=bright), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(memory.features(pixels[6:]), _reference(pixels, 100.0)[6:], rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"pixels must be \(frames, 64, 112, 3\)"):
        memory.features(pixels[0])


def test_small_frame_is_the_encoder_input_at_a_quarter_turned_to_landscape():
    rng = np.random.default_rng(4)
    wide = rng.integers(0, 256, size=(256, 448, 3), dtype=np.uint8)
    small = small_frame(wide)
    assert small.shape == (H, W, 3) and small.dtype == np.float32
    assert 0.0 <= small.min() and small.max() <= 1.0
    np.testing.assert_allclose(small, cv2.resize(wide, SIZE, interpolation=cv2.INTER_AREA) / 255.0, atol=1e-6)
    np.testing.assert_allclose(small_frame(np.ascontiguousarray(np.rot90(wide, -1))), small, atol=1e-6)
