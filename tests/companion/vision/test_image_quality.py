"""PSNR, SSIM, UCIQE and UIQM on images whose values can be worked out by hand."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.vision import image_quality as iq


def _gray(value: float, shape=(32, 32)) -> np.ndarray:
    return np.full((*shape, 3), value, dtype=np.uint8)


def _texture(seed: int = 0, shape=(64, 80)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(*shape, 3), dtype=np.uint8)


def test_psnr_hand_computed():
    a = _gray(100, (4, 4))
    b = a.copy()
    assert iq.psnr(a, b) == math.inf
    b[0, 0] = 104  # one pixel off by 4 in all channels: MSE = 16 / 16 = 1
    assert iq.psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 1.0))  # 48.1308 dB
    assert iq.psnr(_gray(0), _gray(10)) == pytest.approx(10 * math.log10(65025 / 100))  # 28.1308 dB


def test_psnr_refuses_different_shapes():
    with pytest.raises(ValueError, match="differ in shape"):
        iq.psnr(_gray(0, (4, 4)), _gray(0, (4, 5)))


def test_ssim_identity_and_constant_images():
    img = _texture()
    assert iq.ssim(img, img) == pytest.approx(1.0)
    # Two flat images: no variance, no covariance, so SSIM is the luminance term alone.
    c1 = (0.01 * 255) ** 2
    expected = (2 * 100 * 120 + c1) / (100**2 + 120**2 + c1)  # 0.98363...
    assert iq.ssim(_gray(100), _gray(120)) == pytest.approx(expected, abs=1e-9)


def test_ssim_orders_distortions_and_sees_inversion():
    img = _texture(1)
    rng = np.random.default_rng(2)
    small = np.clip(img + rng.normal(0, 5, img.shape), 0, 255).astype(np.uint8)
    large = np.clip(img + rng.normal(0, 40, img.shape), 0, 255).astype(np.uint8)
    assert 1.0 > iq.ssim(img, small) > iq.ssim(img, large)
    assert iq.ssim(img, small) == pytest.approx(iq.ssim(small, img))
    assert iq.ssim(img, 255 - img) < 0


def test_uciqe_gray_and_black_white():
    assert iq.uciqe(_gray(128)) == pytest.approx(0.0, abs=1e-3)
    half = _gray(0, (20, 20))
    half[:, 10:] = 255
    # No chroma, no saturation; L* spans 0..100, so the top and bottom 1% differ by exactly 1.
    assert iq.uciqe(half) == pytest.approx(0.2745, abs=1e-3)


def test_uicm_hand_computed():
    assert iq.uicm(_gray(90)) == pytest.approx(0.0)
    img = np.zeros((10, 10, 3), dtype=np.uint8)
    img[...] = (50, 100, 200)  # B, G, R: RG = 100, YB = 150 - 50 = 100, no spread
    assert iq.uicm(img) == pytest.approx(-0.0268 * math.sqrt(100**2 + 100**2))


def test_uiconm_and_uiqm_hand_computed():
    assert iq.uiqm(_gray(77)) == pytest.approx(0.0)
    stripes = _gray(100, (16, 16))
    stripes[:, ::2] = 200  # every 8x8 block holds min 100 and max 200
    g = 1026.0
    ratio = (g * (200 - 100) / (g - 100)) / (200 + 100 - 200 * 100 / g)
    assert iq.uiconm(stripes) == pytest.approx(-ratio * math.log(ratio))


def test_uism_grows_with_detail():
    rng = np.random.default_rng(3)
    fine = rng.integers(30, 226, size=(64, 64, 3), dtype=np.uint8)
    blurred = cv2.GaussianBlur(fine, (9, 9), 3)
    assert iq.uism(fine) > iq.uism(blurred) > 0
