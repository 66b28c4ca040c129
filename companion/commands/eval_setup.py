"""The configuration and encoder every ``merlion eval`` command starts from."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from companion.errors import MerlionError

if TYPE_CHECKING:
    from companion.config import Config
    from companion.vision.encoders.base import Encoder


def eval_config(args: argparse.Namespace, encoder: str | None) -> Config:
    """``--config`` with ``--encoder`` over it: the commands compare encoders on one configuration."""
    from companion.config import load_config

    overrides = {"encoder": {"name": encoder}} if encoder else None
    return load_config(args.config, overrides=overrides)


def make_encoder(cfg: Config) -> Encoder:
    """The configured encoder: the team's factory, with the visual baseline always available."""
    if cfg.encoder.name == "visual":
        from companion.vision.encoders.visual import VisualEncoder

        return VisualEncoder(cfg.encoder)
    try:
        from companion.vision.encoders.factory import make_encoder as factory
    except ImportError:
        raise MerlionError(f"encoder {cfg.encoder.name!r}: companion.vision.encoders.factory is not installed") from None
    return factory(cfg.encoder)
