"""Build the configured enhancer once, at start-up, so a bad model path or setting fails before any frame flows."""

from __future__ import annotations

from companion.config import EnhanceConfig
from companion.errors import MerlionError
from companion.vision.enhancers.base import Enhancer
from companion.vision.enhancers.classic import ClassicEnhancer
from companion.vision.enhancers.model import ModelEnhancer

METHODS = ("classic", "model")


def make_enhancer(cfg: EnhanceConfig, *, device: str = "auto") -> Enhancer:
    """The enhancer ``cfg.method`` names; raises a one-line MerlionError naming the key for anything wrong.

    ``device`` (auto|cpu|cuda) only matters for ``model``; pass the encoder's device to keep both on one GPU.
    """
    if cfg.method == "classic":
        return ClassicEnhancer()
    if cfg.method == "model":
        return ModelEnhancer(cfg.model_path, input_size=cfg.model_input_size, value_range=cfg.model_value_range,
                             device=device)
    raise MerlionError(f"enhance.method: {cfg.method!r} is not one of {', '.join(METHODS)}", exit_code=2)
