"""A learned image-to-image enhancer (FUnIE-GAN, a diffusion U-Net, ...) exported as TorchScript or ONNX.

Why a probe at load: a model that wants another input size or value range than the config says would otherwise
fail (or silently produce garbage) deep in the live loop. One inference on a dummy frame at start-up turns that
into a one-line error naming the config key and the value.

The model takes and returns one NCHW RGB float32 tensor, 3 channels, in the configured value range
(``0-1``, ``-1-1`` or ``0-255``). Frames are resized to ``model_input_size`` (or to sides divisible by 8 when it
is None), and the output is resized back to the frame's size.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.errors import MerlionError
from companion.vision.enhancers.base import Enhancer
from companion.vision.onnx_runtime import onnxruntime

log = logging.getLogger(__name__)

RANGES: dict[str, tuple[float, float]] = {"0-1": (0.0, 1.0), "-1-1": (-1.0, 1.0), "0-255": (0.0, 255.0)}
RANGE_SLACK = 0.25
"""How far (as a share of the range's width) the probe output may stray outside the range before it is refused."""
MIN_SPREAD = 0.02
"""The probe frame spans most of the range; an output using less than this share of it means another range."""
TORCHSCRIPT_SUFFIXES = (".pt", ".pth", ".ts", ".torchscript")


def _resolve_device(device: str) -> str:
    if device == "cpu":
        return "cpu"
    import torch  # 3.2 s (measured): only for a torch enhancer model, never for classic or ONNX

    if device == "cuda" and not torch.cuda.is_available():
        raise MerlionError("enhance: device cuda asked for but CUDA is not available", exit_code=2)
    return "cuda" if torch.cuda.is_available() else "cpu"


class _TorchScriptRunner:
    def __init__(self, path: Path, device: str) -> None:
        import torch  # 3.2 s (measured): only for a TorchScript model

        self._torch = torch
        self.device = device
        try:
            with warnings.catch_warnings():  # TorchScript is deprecated upstream but still what exporters ship
                warnings.simplefilter("ignore", FutureWarning)
                self.module = torch.jit.load(str(path), map_location=device).eval()
        except Exception as err:  # torch raises RuntimeError/ValueError with long texts
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise MerlionError(f"enhance.model_path: {path} is not a TorchScript model ({first})",
                               exit_code=2) from None
        self.fixed_size: tuple[int, int] | None = None

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        torch = self._torch
        with torch.inference_mode():
            out = self.module(torch.from_numpy(batch).to(self.device))
        if isinstance(out, (tuple, list)):
            out = out[0]
        return out.float().cpu().numpy()


class _OnnxRunner:
    def __init__(self, path: Path, device: str) -> None:
        ort = onnxruntime(f"enhance.model_path {path.name}")
        providers = ["CPUExecutionProvider"]
        if device == "cuda" and "CUDAExecutionProvider" in ort.get_available_providers():
            providers.insert(0, "CUDAExecutionProvider")
        try:
            self.session = ort.InferenceSession(str(path), providers=providers)
        except Exception as err:
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise MerlionError(f"enhance.model_path: {path} is not a usable ONNX model ({first})",
                               exit_code=2) from None
        self.device = "cuda" if self.session.get_providers()[0] == "CUDAExecutionProvider" else "cpu"
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = list(inp.shape)
        if len(shape) != 4:
            raise MerlionError(f"enhance.model_path: {path} takes a {len(shape)}-D input, expected N x 3 x H x W",
                               exit_code=2)
        h, w = shape[2], shape[3]
        self.fixed_size = (w, h) if isinstance(h, int) and isinstance(w, int) else None

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        return np.asarray(self.session.run(None, {self.input_name: batch})[0], dtype=np.float32)


class ModelEnhancer(Enhancer):
    """Runs an exported network on each frame; checked by a probe inference when it is built."""

    name = "model"

    def __init__(
        self,
        path: str | Path | None,
        *,
        input_size: tuple[int, int] | None = None,
        value_range: str = "0-1",
        device: str = "auto",
    ) -> None:
        if path is None or str(path) == "":
            raise MerlionError("enhance.model_path: required for enhance.method model", exit_code=2)
        self.path = Path(path)
        if not self.path.is_file():
            raise MerlionError(f"enhance.model_path: no such file: {self.path}", exit_code=2)
        if value_range not in RANGES:
            raise MerlionError(f"enhance.model_value_range: {value_range!r} is not one of {', '.join(RANGES)}",
                               exit_code=2)
        if input_size is not None and (len(input_size) != 2 or min(input_size) <= 0):
            raise MerlionError(f"enhance.model_input_size: {input_size} is not a (width, height) pair", exit_code=2)
        self.value_range = value_range
        suffix = self.path.suffix.lower()
        dev = _resolve_device(device)
        if suffix == ".onnx":
            self._runner: Any = _OnnxRunner(self.path, dev)
            self.format = "onnx"
        elif suffix in TORCHSCRIPT_SUFFIXES:
            self._runner = _TorchScriptRunner(self.path, dev)
            self.format = "torchscript"
        else:
            raise MerlionError(f"enhance.model_path: {self.path} must end in .onnx or "
                               f"{'/'.join(TORCHSCRIPT_SUFFIXES)}", exit_code=2)
        fixed = self._runner.fixed_size
        if input_size is not None and fixed is not None and tuple(input_size) != fixed:
            raise MerlionError(f"enhance.model_input_size: {tuple(input_size)} but {self.path.name} takes "
                               f"{fixed[0]}x{fixed[1]} (width x height)", exit_code=2)
        self.input_size: tuple[int, int] | None = tuple(input_size) if input_size else fixed
        self.device = self._runner.device
        self._probe()

    def describe(self) -> dict:
        return {"name": self.name, "path": str(self.path), "format": self.format, "device": self.device,
                "input_size": self.input_size, "value_range": self.value_range}

    def _model_size(self, width: int, height: int) -> tuple[int, int]:
        if self.input_size is not None:
            return self.input_size
        return max(8, width // 8 * 8), max(8, height // 8 * 8)

    def _to_tensor(self, image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        if (image.shape[1], image.shape[0]) != size:
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB).astype(np.float32) * (1.0 / 255.0)
        lo, hi = RANGES[self.value_range]
        x = rgb * (hi - lo) + lo
        return np.ascontiguousarray(x.transpose(2, 0, 1)[None])

    def _run(self, image: np.ndarray) -> np.ndarray:
        size = self._model_size(image.shape[1], image.shape[0])
        batch = self._to_tensor(image, size)
        try:
            out = self._runner(batch)
        except MerlionError:
            raise
        except Exception as err:
            text = str(err).strip().splitlines()
            first = text[-1] if text else type(err).__name__
            raise MerlionError(f"enhance.model_input_size: {self.path.name} rejected a 1x3x{size[1]}x{size[0]} "
                               f"input ({first[:200]})", exit_code=2) from None
        if out.ndim != 4 or out.shape[0] != 1 or out.shape[1] != 3:
            raise MerlionError(f"enhance.model_path: {self.path.name} returned shape {tuple(out.shape)}, "
                               f"expected 1x3xHxW", exit_code=2)
        return out[0]

    def _probe(self) -> None:
        rng = np.random.default_rng(0)
        h, w = (self.input_size[1], self.input_size[0]) if self.input_size else (64, 64)
        dummy = rng.integers(40, 216, size=(h, w, 3), dtype=np.uint8)
        out = self._run(dummy)
        lo, hi = RANGES[self.value_range]
        slack = RANGE_SLACK * (hi - lo)
        omin, omax = float(out.min()), float(out.max())
        if not np.isfinite(out).all() or omin < lo - slack or omax > hi + slack:
            raise MerlionError(f"enhance.model_value_range: {self.value_range} but {self.path.name} returned "
                               f"values in [{omin:.3g}, {omax:.3g}] for a probe frame", exit_code=2)
        if omax - omin < MIN_SPREAD * (hi - lo):
            raise MerlionError(f"enhance.model_value_range: {self.value_range} but {self.path.name} returned "
                               f"only [{omin:.3g}, {omax:.3g}] for a textured probe frame (another range?)",
                               exit_code=2)
        log.info("enhancer model %s (%s) on %s, input %s, range %s", self.path.name, self.format, self.device,
                 self.input_size or "any (sides divisible by 8)", self.value_range)

    def enhance(self, image: np.ndarray) -> np.ndarray:
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"expected a BGR uint8 HxWx3 image, got {image.dtype} {image.shape}")
        out = self._run(image)
        lo, hi = RANGES[self.value_range]
        rgb = (out.transpose(1, 2, 0) - lo) * (255.0 / (hi - lo))
        rgb = np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        if bgr.shape[:2] != image.shape[:2]:
            bgr = cv2.resize(bgr, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_LINEAR)
        return bgr
