"""Builds the configured encoder; ``auto`` takes CLIP when its weights are on disk, else the packaged one.

The choice is logged as a WARNING either way: an operator who expected CLIP and got the ImageNet fallback (or the
reverse) must see it in the first lines of the log, since scores and thresholds depend on it.
"""

from __future__ import annotations

import logging

from companion.config import EncoderConfig
from companion.vision.encoders.base import Encoder

log = logging.getLogger(__name__)


def make_encoder(cfg: EncoderConfig) -> Encoder:
    """The encoder ``cfg.name`` asks for (auto | clip | imagenet | visual); MerlionError when it cannot load."""
    name = cfg.name
    if name == "auto" and cfg.runtime == "onnx" and not cfg.weights:
        # torch-free: a tag a child process found on an earlier start
        from companion.vision.encoders.onnx_clip import recorded_weights

        if recorded_weights(cfg) is not None:
            log.warning("encoder auto: using CLIP %s (weights found offline on an earlier start)", cfg.model)
            name = "clip"
    if name == "auto":
        from companion.vision.encoders.weights import (
            clip_weights_available,  # imports open_clip: only when needed
        )

        ok, why_not = clip_weights_available(cfg.model, cfg.weights, cfg.pretrained)
        if ok:
            log.warning("encoder auto: using CLIP %s (weights found offline)", cfg.model)
            name = "clip"
        else:
            log.warning("encoder auto: using the packaged imagenet encoder (EfficientNet-Lite0), because %s",
                        why_not)
            name = "imagenet"
    if name == "clip" and cfg.runtime == "onnx":
        from companion.vision.encoders.onnx_clip import OnnxClipEncoder  # never imports torch

        return OnnxClipEncoder(cfg)
    if name == "clip":
        from companion.vision.encoders.clip import ClipEncoder

        return ClipEncoder(cfg)
    if name == "imagenet":
        from companion.vision.encoders.imagenet import ImageNetEncoder

        return ImageNetEncoder(cfg)
    if name == "visual":
        from companion.vision.encoders.visual import VisualEncoder

        return VisualEncoder(cfg)
    raise ValueError(f"unknown encoder {name!r}")  # EncoderConfig's Literal makes this unreachable from config
