"""Fixtures shared by the vision tests."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.conftest import shared_file


@pytest.fixture(autouse=True, scope="module")
def _cache_in_tmp(tmp_path_factory):
    """CLIP keeps query embeddings and exported towers between starts in the default encoder.cache_dir
    (~/.cache/merlion): keep the tests' out of the user's cache, one per module, so the queries several tests
    of a module ask are encoded by one child process."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("HOME", str(tmp_path_factory.mktemp("home")))
        yield


@pytest.fixture(scope="module")
def images() -> list[np.ndarray]:
    """Real frames of several shapes: 4:3, near-square, 16:9, portrait, and one smaller than the model input."""
    suim = cv2.imread(str(shared_file("suim/images/f_r_1965_.jpg")))
    square = cv2.imread(str(shared_file("suim/images/d_r_47_.jpg")))
    wide = cv2.imread(str(shared_file("aquarium_fish/frames/000001.jpg")))
    return [suim, square, wide, np.ascontiguousarray(wide[:, 300:600]), cv2.resize(suim, (160, 120))]
