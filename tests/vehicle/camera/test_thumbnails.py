"""Thumbnails fit their byte budget, keep the aspect ratio and use the best quality that fits."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vehicle.surface_env import scene
from vehicle.camera.thumbnails import _encode, fit_size, make_thumbnail


@pytest.mark.parametrize("budget", [300, 1000, 2500, 8000])
def test_fits_the_budget_with_the_best_quality(budget):
    img = scene(1, 640, 360)
    thumb = make_thumbnail(img, budget, max_side=160)
    assert len(thumb.data) <= budget
    assert abs(thumb.width / thumb.height - 640 / 360) < 0.05
    decoded = cv2.imdecode(np.frombuffer(thumb.data, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape[:2] == (thumb.height, thumb.width)
    if thumb.quality < 95:  # one step better would not have fitted at this size
        small = cv2.resize(img, (thumb.width, thumb.height), interpolation=cv2.INTER_AREA)
        assert len(_encode(small, "jpeg", thumb.quality + 1)) > budget


def test_shrinks_when_quality_alone_cannot_fit():
    img = (np.random.default_rng(0).random((480, 640, 3)) * 255).astype(np.uint8)  # pure noise
    thumb = make_thumbnail(img, 400, max_side=160)
    assert len(thumb.data) <= 400 and max(thumb.width, thumb.height) < 160


def test_webp_and_grey_and_errors():
    webp = make_thumbnail(scene(2), 1500, fmt="webp")
    assert webp.data[:4] == b"RIFF" and webp.data[8:12] == b"WEBP" and len(webp.data) <= 1500
    grey = make_thumbnail(cv2.cvtColor(scene(3), cv2.COLOR_BGR2GRAY), 800)
    assert len(grey.data) <= 800
    with pytest.raises(ValueError, match="cannot fit"):
        make_thumbnail(scene(4), 40)
    with pytest.raises(ValueError, match="non-empty"):
        make_thumbnail(np.zeros((0, 0, 3), np.uint8), 2500)
    assert fit_size(100, 50, 160) == (100, 50)  # never upscaled
    assert fit_size(1920, 1080, 160) == (160, 90)
