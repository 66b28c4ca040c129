"""The packaged encoder is the offline default (README: no weights needed): a new user's first `summarize`,
`score` and `demo`, with empty CLIP caches, get their output without a WARNING about CLIP weights in it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.conftest import run_merlion, shared_file


@pytest.mark.parametrize("command", ["summarize", "score", "demo"])
def test_no_clip_weights_is_no_alarm_for_the_default_encoder(tmp_path, command):
    env = {"HOME": str(tmp_path), "HF_HOME": str(tmp_path / "hf"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    image = tmp_path / "frame.png"
    cv2.imwrite(str(image), np.full((64, 64, 3), 90, np.uint8))
    args = {"summarize": [str(shared_file("survey/survey_480x270.mp4")), "--out", str(tmp_path / "out"),
                          "--fps", "1"],
            "score": [str(image)],
            "demo": ["--duration", "3", "--out", str(tmp_path / "demo")]}[command]
    proc = run_merlion(command, *args, env=env, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip()
    assert "WARNING" not in proc.stderr and "no CLIP weights" not in proc.stderr, proc.stderr
    assert "imagenet" in (proc.stdout + proc.stderr + (tmp_path / "out" / "summary.json").read_text()
                          if command == "summarize" else proc.stdout + proc.stderr)
