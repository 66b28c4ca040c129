"""Command-line options as a nested configuration override, shared by the commands that score frames.

Only options the user gave go in (argparse leaves the others None), so a value from ``--config`` or the
environment is overridden only where the command line says so.
"""

from __future__ import annotations

import argparse
from typing import Any

Overrides = dict[str, dict[str, Any]]

ENCODER_OPTIONS = ("model", "weights", "pretrained", "precision", "batch")


def put(over: Overrides, section: str, key: str, value: Any) -> None:
    """Set ``section.key`` unless ``value`` is None (the option was not given)."""
    if value is not None:
        over.setdefault(section, {})[key] = value


def put_queries_and_encoder(over: Overrides, args: argparse.Namespace) -> None:
    """--query/--negative and --encoder with its options (those the command defines)."""
    put(over, "queries", "positive", args.query)
    if args.negative is not None:
        put(over, "queries", "negatives", args.negative)
    elif args.query is not None:
        put(over, "queries", "negatives", [])  # the default negative belongs to the default positive
    put(over, "encoder", "name", args.encoder)
    for key in ENCODER_OPTIONS:
        put(over, "encoder", key, getattr(args, key, None))
