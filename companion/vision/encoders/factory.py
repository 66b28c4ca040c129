"""Builds the configured encoder; ``auto`` takes CLIP when its weights are on disk, else the packaged one.

The choice is logged at INFO either way, in the first lines of the log (scores and thresholds depend on it), but as
no alarm: the packaged encoder is the offline default the README promises, so a start without CLIP weights is
the normal case, not a fault (it was a WARNING, which landed in the middle of every new user's first
``summarize``). Why CLIP was not taken is at DEBUG (``-vv``); asking for ``clip`` without weights is an error.
"""

from __future__ import annotations

import logging

from companion.config import EncoderConfig
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.onnx_clip import OnnxClipEncoder, recorded_weights
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.encoders.weights import clip_weights_available

log = logging.getLogger(__name__)


def make_encoder(cfg: EncoderConfig) -> Encoder:
    """The encoder ``cfg.name`` asks for (auto | clip | imagenet | visual); MerlionError when it cannot load."""
    name = cfg.name
    if name == "auto" and cfg.runtime == "onnx" and not cfg.weights:
        # torch-free: a tag a child process found on an earlier start
        if recorded_weights(cfg) is not None:
            log.info("encoder auto: using CLIP %s (weights found offline on an earlier start)", cfg.model)
            name = "clip"
    if name == "auto":
        ok, why_not = clip_weights_available(cfg.model, cfg.weights, cfg.pretrained)
        if ok:
            log.info("encoder auto: using CLIP %s (weights found offline)", cfg.model)
            name = "clip"
        else:
            log.info("encoder auto: using the packaged imagenet encoder (EfficientNet-Lite0), the offline default; "
                     "CLIP %s is used instead once its weights are on disk (merlion models list)", cfg.model)
            log.debug("encoder auto: not CLIP, because %s", why_not)
            name = "imagenet"
    if name == "clip" and cfg.runtime == "onnx":
        return OnnxClipEncoder(cfg)
    if name == "clip":
        # torch + open_clip: 8.3 s (measured), only for this encoder
        from companion.vision.encoders.clip import ClipEncoder

        return ClipEncoder(cfg)
    if name == "imagenet":
        # torch: 3.1 s (measured), only for this encoder
        from companion.vision.encoders.imagenet import ImageNetEncoder

        return ImageNetEncoder(cfg)
    if name == "visual":
        return VisualEncoder(cfg)
    raise ValueError(f"unknown encoder {name!r}")  # EncoderConfig's Literal makes this unreachable from config
