"""``merlion enhance`` and ``merlion bench enhance`` as a user runs them: real subprocesses, real files."""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import torch
from torch import nn

from companion.bench.enhance_bench import synthetic_murky_frames
from tests.conftest import run_merlion


def _write_images(folder, count=3, size=(96, 64)):
    folder.mkdir(parents=True, exist_ok=True)
    frames = synthetic_murky_frames(count, size, seed=5)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"frame_{i:02d}.png"), frame)
    return frames


def test_enhance_folder_side_by_side(tmp_path):
    frames = _write_images(tmp_path / "in")
    result = run_merlion("enhance", str(tmp_path / "in"), str(tmp_path / "out"), "--side-by-side")
    assert result.returncode == 0, result.stderr
    assert "enhanced 3 frame(s) with classic" in result.stdout
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["frame_00.png", "frame_01.png", "frame_02.png"]
    out = cv2.imread(str(tmp_path / "out" / "frame_01.png"))
    assert out.shape == (64, 192, 3)
    assert np.array_equal(out[:, :96], frames[1])
    assert not np.array_equal(out[:, 96:], frames[1])


def test_enhance_refuses_overwrite_and_bad_model_in_one_line(tmp_path):
    _write_images(tmp_path / "in", count=1)
    src = tmp_path / "in" / "frame_00.png"
    before = src.read_bytes()
    result = run_merlion("enhance", str(src), str(src))
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [f"merlion: error: {src}: would overwrite an input; choose another"
                                                   " output"]
    assert src.read_bytes() == before
    missing = tmp_path / "nope.onnx"
    result = run_merlion("enhance", str(src), str(tmp_path / "o.png"), "--model", str(missing))
    assert result.returncode == 2
    assert result.stderr.strip() == f"merlion: error: enhance.model_path: no such file: {missing}"
    assert not (tmp_path / "o.png").exists()


def test_enhance_with_an_onnx_model_from_the_config(tmp_path):
    net = nn.Sequential(nn.Conv2d(3, 3, 1), nn.Sigmoid()).eval()
    model = tmp_path / "tiny.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, torch.rand(1, 3, 32, 32), str(model), input_names=["x"], output_names=["y"],
                          dynamo=False)
    cfg = tmp_path / "merlion.yaml"
    cfg.write_text(f"enhance:\n  method: model\n  model_path: {model}\n  model_value_range: '0-1'\n")
    _write_images(tmp_path / "in", count=2)
    result = run_merlion("enhance", "-c", str(cfg), str(tmp_path / "in"), str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    assert "with model" in result.stdout
    out = cv2.imread(str(tmp_path / "out" / "frame_00.png"))
    assert out.shape == (64, 96, 3)
    # The same model declared 0-255 is refused at start-up, naming the key, before anything is written.
    result = run_merlion("enhance", "-c", str(cfg), "--value-range", "0-255", str(tmp_path / "in"),
                         str(tmp_path / "out2"))
    assert result.returncode == 2
    assert result.stderr.strip().startswith("merlion: error: enhance.model_value_range: 0-255 but tiny.onnx")
    assert not (tmp_path / "out2").exists()


def test_bench_enhance_json_and_quality(tmp_path):
    frames = _write_images(tmp_path / "imgs", count=2)
    pairs = tmp_path / "pairs"
    (pairs / "A").mkdir(parents=True)
    (pairs / "GTr_A").mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(pairs / "A" / f"{i}.png"), frame)
        cv2.imwrite(str(pairs / "GTr_A" / f"{i}.png"), cv2.convertScaleAbs(frame, alpha=1.2, beta=-20))
    result = run_merlion("bench", "enhance", "--method", "classic", "--json", "--seconds", "0.2",
                         "--quality", str(pairs), str(tmp_path / "imgs"))
    assert result.returncode == 0, result.stderr
    last = json.loads(result.stdout.strip().splitlines()[-1])
    assert last["fps_256"] > 0 and last["fps_live"] > 0
    assert last["cpu_ms_256"] > 0 and last["cpu_ms_live"] > 0
    assert last["live_size"] == [640, 480] and last["method"] == "classic"
    assert last["quality"]["pairs"] == 2
    assert last["no_reference"]["images"] == 2
    assert "frames/s at 256x256" in result.stdout
