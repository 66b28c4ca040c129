"""ONNX Runtime is not in the base install: asking for an ONNX model without it is one line saying how to get it.

The test extras install onnxruntime, so its absence is made with a module of that name on PYTHONPATH that fails to
import, as a missing package does."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.conftest import run_merlion, shared_file


@pytest.fixture
def without_onnxruntime(tmp_path: Path) -> dict[str, str]:
    hidden = tmp_path / "hidden"
    hidden.mkdir()
    (hidden / "onnxruntime.py").write_text('raise ImportError("No module named \'onnxruntime\'")\n')
    return {"PYTHONPATH": os.pathsep.join([str(hidden), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


@pytest.mark.parametrize("ask", ["enhancer", "encoder"])
def test_an_onnx_model_without_onnxruntime_is_one_line_naming_the_setting(tmp_path, without_onnxruntime, ask):
    image = shared_file("suim/images/n_l_12_.jpg")
    if ask == "enhancer":
        model = tmp_path / "waternet.onnx"
        model.write_bytes(b"\x08\x07")  # never read: the runtime is asked for first
        proc = run_merlion("enhance", str(image), str(tmp_path / "out.jpg"), "--model", str(model),
                           env=without_onnxruntime)
        setting = "enhance.model_path waternet.onnx"
    else:
        cfg = tmp_path / "onnx.yaml"
        cfg.write_text("encoder:\n  name: clip\n  runtime: onnx\n")
        proc = run_merlion("score", str(image), "--config", str(cfg), env=without_onnxruntime)
        setting = "encoder.runtime onnx"
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines == [f"merlion: error: {setting} needs ONNX Runtime, which the base install does not bring: "
                     'pip install "merlion-companion[onnx]"'], proc.stderr
    assert not (tmp_path / "out.jpg").exists()
