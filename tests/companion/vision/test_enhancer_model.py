"""Learned enhancers: tiny networks built here, exported to TorchScript and ONNX, loaded through the config."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from torch import nn

from companion.config import EnhanceConfig
from companion.errors import MerlionError
from companion.vision.enhancers.factory import make_enhancer
from companion.vision.enhancers.model import ModelEnhancer

pytestmark = pytest.mark.filterwarnings("ignore::FutureWarning")  # torch.jit.script/trace deprecation


class Affine(nn.Module):
    """A 1x1 convolution computing ``scale * x + shift`` per channel, then an optional clamp."""

    def __init__(self, scale: float = 1.0, shift: float = 0.0, channels_out: int = 3) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, channels_out, 1)
        with torch.no_grad():
            self.conv.weight.zero_()
            for i in range(channels_out):
                self.conv.weight[i, i % 3, 0, 0] = scale
            self.conv.bias.fill_(shift)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


class FixedSize(nn.Module):
    """Only works on 1x3x16x16 inputs (a linear layer over the flattened image)."""

    def __init__(self) -> None:
        super().__init__()
        self.fc = nn.Linear(3 * 16 * 16, 3 * 16 * 16)
        with torch.no_grad():
            self.fc.weight.copy_(torch.eye(3 * 16 * 16))
            self.fc.bias.zero_()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(x.reshape(1, -1)).reshape(1, 3, 16, 16)


def _onnx(module: nn.Module, path, size=(32, 32), dynamic=True) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module.eval(), torch.rand(1, 3, size[1], size[0]), str(path), input_names=["x"], output_names=["y"],
            dynamic_axes={"x": {2: "h", 3: "w"}, "y": {2: "h", 3: "w"}} if dynamic else None, dynamo=False,
        )
    return str(path)


def _image(w=64, h=48) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(20, 236, size=(h, w, 3), dtype=np.uint8)


@pytest.mark.parametrize("value_range", ["0-1", "-1-1", "0-255"])
@pytest.mark.parametrize("export", ["script", "trace", "onnx"])
def test_identity_round_trips_every_range(tmp_path, export, value_range):
    net = Affine().eval()
    if export == "onnx":
        path = _onnx(net, tmp_path / "id.onnx")
    else:
        path = str(tmp_path / "id.pt")
        exported = torch.jit.script(net) if export == "script" else torch.jit.trace(net, torch.rand(1, 3, 8, 8))
        exported.save(path)
    enh = make_enhancer(EnhanceConfig(method="model", model_path=path, model_value_range=value_range), device="cpu")
    img = _image()
    out = enh.enhance(img)
    assert out.shape == img.shape and out.dtype == np.uint8
    assert np.abs(out.astype(int) - img).max() <= 1
    assert enh.describe()["format"] == ("onnx" if export == "onnx" else "torchscript")


def test_model_output_is_used_and_resized_back(tmp_path):
    path = tmp_path / "dim.pt"
    torch.jit.script(Affine(scale=0.5).eval()).save(str(path))
    enh = ModelEnhancer(path, input_size=(32, 32), device="cpu")
    img = np.full((50, 70, 3), 200, np.uint8)
    out = enh.enhance(img)
    assert out.shape == img.shape
    assert np.abs(out.astype(int) - 100).max() <= 1


def test_fixed_size_onnx_sets_the_input_size_and_refuses_another(tmp_path):
    path = _onnx(Affine(), tmp_path / "fixed.onnx", size=(48, 32), dynamic=False)
    enh = ModelEnhancer(path, device="cpu")
    assert enh.input_size == (48, 32)
    assert enh.enhance(_image(100, 60)).shape == (60, 100, 3)
    with pytest.raises(MerlionError, match=r"enhance\.model_input_size: \(64, 64\) but fixed\.onnx takes 48x32"):
        ModelEnhancer(path, input_size=(64, 64), device="cpu")


def test_wrong_shape_is_caught_by_the_probe(tmp_path):
    path = tmp_path / "fixed16.pt"
    torch.jit.trace(FixedSize().eval(), torch.rand(1, 3, 16, 16)).save(str(path))
    assert ModelEnhancer(path, input_size=(16, 16), device="cpu").enhance(_image()).shape == (48, 64, 3)
    with pytest.raises(MerlionError, match=r"^enhance\.model_input_size: fixed16\.pt rejected a 1x3x32x32 input"):
        ModelEnhancer(path, input_size=(32, 32), device="cpu")
    one = tmp_path / "one.pt"
    torch.jit.script(Affine(channels_out=1).eval()).save(str(one))
    with pytest.raises(MerlionError, match=r"returned shape \(1, 1, 64, 64\), expected 1x3xHxW"):
        ModelEnhancer(one, device="cpu")


def test_wrong_range_is_caught_by_the_probe(tmp_path):
    wide = tmp_path / "wide.pt"
    torch.jit.script(Affine(scale=255.0).eval()).save(str(wide))  # really a 0-255 output
    with pytest.raises(MerlionError, match=r"^enhance\.model_value_range: 0-1 but wide\.pt returned values"):
        ModelEnhancer(wide, value_range="0-1", device="cpu")
    squash = tmp_path / "squash.onnx"
    _onnx(nn.Sequential(Affine(), nn.Sigmoid()), squash)  # a 0-1 output asked to be 0-255
    with pytest.raises(MerlionError, match=r"enhance\.model_value_range: 0-255 but squash\.onnx returned only"):
        ModelEnhancer(squash, value_range="0-255", device="cpu")


def test_bad_files_are_one_line_errors(tmp_path):
    for name, pattern in [("junk.pt", "is not a TorchScript model"), ("junk.onnx", "is not a usable ONNX model"),
                          ("junk.bin", "must end in .onnx or")]:
        path = tmp_path / name
        path.write_bytes(b"\x00garbage\x01" * 10)
        with pytest.raises(MerlionError, match=pattern) as info:
            ModelEnhancer(path, device="cpu")
        assert "\n" not in str(info.value) and str(info.value).startswith("enhance.model_path: ")
