"""open_clip's eval transform without torch: BGR uint8 frame -> the model's normalised float32 input, in numpy.

The ONNX Runtime encoder runs in a process that never imports torch, so it cannot call open_clip's transform.
The resize is PIL's, as in open_clip (torchvision resizes a PIL image with ``Image.resize``): OpenCV's bicubic
filter does not widen its kernel when it shrinks, so it cannot give the same pixels on a downscale. The rest
(short side to the model's size with the long side truncated, centre crop rounded as torchvision does, /255,
(x - mean) / std in float32) is numpy. A test holds it to open_clip's transform (tests/companion/vision/
test_onnx_clip.py): same uint8 pixels after the resize, and the normalised input within 1e-5.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from PIL import Image

from companion.errors import UsageError

_RESAMPLE = {"bicubic": Image.Resampling.BICUBIC, "bilinear": Image.Resampling.BILINEAR,
             "nearest": Image.Resampling.NEAREST}
OPENAI_MEAN = (0.48145466, 0.4578275, 0.40821073)
OPENAI_STD = (0.26862954, 0.26130258, 0.27577711)
"""open_clip's defaults (open_clip.constants.OPENAI_DATASET_MEAN/STD), for a manifest that names none."""


def as_pair(size: int | Sequence[int]) -> tuple[int, int]:
    """open_clip sizes are an int or (height, width)."""
    if isinstance(size, int):
        return size, size
    return int(size[0]), int(size[1])


def resize_shape(h: int, w: int, size: tuple[int, int], mode: str) -> tuple[int, int]:
    """(height, width) a frame is resized to before the centre crop, as torchvision's Resize computes it: the
    short side becomes the input side and the long side is truncated, not rounded ("squash": the input size)."""
    th, tw = size
    if mode == "squash":
        return th, tw
    if h <= w:
        return th, int(th * w / h)
    return int(tw * h / w), tw


class NumpyClipPreprocess:
    """The "shortest" (square input) and "squash" resize modes of open_clip's eval transform."""

    def __init__(self, cfg: dict) -> None:
        self.size = as_pair(cfg.get("size", 224))
        self.mode = cfg.get("resize_mode", "shortest")
        interpolation = cfg.get("interpolation", "bicubic")
        if self.mode not in ("shortest", "squash") or (self.mode == "shortest" and self.size[0] != self.size[1]):
            raise UsageError(f"encoder.runtime onnx: the model's resize mode {self.mode!r} at size {self.size} is "
                             f"not supported without torch (shortest with a square input, or squash); "
                             f"use encoder.runtime torch")
        if interpolation not in _RESAMPLE:
            raise UsageError(f"encoder.runtime onnx: the model's interpolation {interpolation!r} is not supported "
                             f"(bicubic, bilinear, nearest); use encoder.runtime torch")
        self.resample = _RESAMPLE[interpolation]
        self.mean = np.asarray(cfg.get("mean") or OPENAI_MEAN, dtype=np.float32).reshape(3, 1, 1)
        self.std = np.asarray(cfg.get("std") or OPENAI_STD, dtype=np.float32).reshape(3, 1, 1)

    def resized(self, bgr: np.ndarray) -> np.ndarray:
        """RGB uint8 (h, w, 3) at the model's size: resized as torchvision's Resize, then centre-cropped."""
        h, w = bgr.shape[:2]
        th, tw = self.size
        new_h, new_w = resize_shape(h, w, self.size, self.mode)
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
        if (new_h, new_w) != (h, w):
            rgb = np.asarray(Image.fromarray(rgb).resize((new_w, new_h), self.resample))
        top = int(round((new_h - th) / 2.0))
        left = int(round((new_w - tw) / 2.0))
        return rgb[top:top + th, left:left + tw]

    def __call__(self, bgr: np.ndarray) -> np.ndarray:
        """BGR uint8 (H, W, 3) -> normalised float32 (3, h, w)."""
        x = self.resized(bgr).transpose(2, 0, 1).astype(np.float32) / np.float32(255.0)
        return (x - self.mean) / self.std

    def batch(self, frames: Sequence[np.ndarray]) -> np.ndarray:
        return np.stack([self(f) for f in frames]) if frames else np.zeros((0, 3, *self.size), np.float32)
