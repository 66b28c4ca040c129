"""Output folders that cannot be made: one error naming the folder, never an OSError traceback.

/proc/self exists but refuses new entries, even to root (tests here often run as root, where permission bits
would not stop anything).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.config import load_config
from companion.errors import MerlionError
from companion.evaluation.compare import compare
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.enhancers.classic import ClassicEnhancer
from companion.vision.enhancers.files import enhance_path
from tests.conftest import shared_file


def test_enhance_into_a_folder_that_cannot_be_made(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    cv2.imwrite(str(src / "a.png"), np.full((32, 32, 3), 80, np.uint8))
    with pytest.raises(MerlionError, match=r"^/proc/self/out: cannot create the output folder \("):
        enhance_path(ClassicEnhancer(), src, "/proc/self/out", progress=False)


def test_compare_into_a_folder_that_cannot_be_made():
    video = shared_file("survey/survey_480x270.mp4")
    labels = shared_file("survey/survey_480x270_labels.csv")
    with pytest.raises(MerlionError, match=r"^--out /proc/self/cmp: cannot create the folder \("):
        compare(video, labels, load_config(None, environ={}), lambda cfg: VisualEncoder(), out_dir="/proc/self/cmp",
                scores=False)
