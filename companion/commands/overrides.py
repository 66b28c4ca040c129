"""Command-line options as a nested configuration override, shared by the commands that score frames.

Only options the user gave go in (argparse leaves the others None), so a value from ``--config`` or the
environment is overridden only where the command line says so.
"""

from __future__ import annotations

import argparse
from typing import Any

from companion.errors import UsageError

Overrides = dict[str, dict[str, Any]]

ENCODER_OPTIONS = ("model", "weights", "pretrained", "precision", "batch")
OPTION_NAMES = {"sampler.k": "-k", "queries.tau_ss": "--threshold", "source.fps": "--fps", "encoder.batch": "--batch",
                "queries.positive": "--query", "queries.negatives": "--negative", "queries.topics": "--topic",
                "encoder.model": "--model", "encoder.weights": "--weights", "enhance.mode": "--enhance"}
"""The option that sets each key, so a bad value is blamed on what the user typed (``load_config(options=)``)."""


def put(over: Overrides, section: str, key: str, value: Any) -> None:
    """Set ``section.key`` unless ``value`` is None (the option was not given)."""
    if value is not None:
        over.setdefault(section, {})[key] = value


def check_queries(positive: str | None, negatives: list[str] | None, where: str = "--query") -> None:
    """An empty query, or a negative that is the positive itself, is refused in words the user typed: the
    library's "String should have at least 1 character" names no fix, and a negative equal to the positive scores
    every frame 0.5 in silence (a softmax over two equal queries)."""
    if positive is not None and not positive.strip():
        raise UsageError(f"{where}: empty (name a thing to look for, e.g. 'fish')")
    option = "--negative" if where == "--query" else f"{where}: negative"
    for negative in negatives or []:
        if not negative.strip():
            raise UsageError(f"{option}: empty (name what the wanted frames do not show, or leave it out)")
        if positive is not None and " ".join(negative.lower().split()) == " ".join(positive.lower().split()):
            raise UsageError(f"{option} {negative!r}: the same as the positive query, so every frame would "
                             f"score 0.5; give a different negative or leave it out")


def put_queries_and_encoder(over: Overrides, args: argparse.Namespace) -> None:
    """--query/--negative (or --topic) and --encoder with its options (those the command defines)."""
    check_queries(args.query, args.negative)
    for topic in getattr(args, "topic", None) or []:
        check_queries(topic["positive"], topic["negatives"], where=f"--topic {topic['name']}")
    put(over, "queries", "positive", args.query)
    if args.query is not None and not getattr(args, "topic", None):
        put(over, "queries", "topics", [])  # the command line's one query replaces topics a config file lists
    if args.negative is not None:
        put(over, "queries", "negatives", args.negative)
    elif args.query is not None:
        put(over, "queries", "negatives", [])  # the default negative belongs to the default positive
    put(over, "encoder", "name", args.encoder)
    for key in ENCODER_OPTIONS:
        put(over, "encoder", key, getattr(args, key, None))
    if getattr(args, "topic", None):
        put(over, "queries", "topics", list(args.topic))


def topic_option(text: str) -> dict[str, Any]:
    """``NAME=POSITIVE[;NEGATIVE...]`` as a ``queries.topics`` entry (argparse turns ValueError into a usage error)."""
    name, sep, queries = text.partition("=")
    parts = [q.strip() for q in queries.split(";") if q.strip()]
    if not sep or not name.strip() or not parts:
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME=POSITIVE[;NEGATIVE...]")
    return {"name": name.strip(), "positive": parts[0], "negatives": parts[1:]}


PRECISIONS = ("auto", "fp32", "fp16-weights", "bf16", "fp16", "int8")
"""``companion.config.Precision``'s values, for ``--precision``'s choices without importing the configuration
(pydantic, 0.15-0.25 s measured) into every ``merlion`` call; tests/companion/commands/test_help_speed.py checks
that the two agree."""

NEGATIVE_HELP = ("negative query, repeatable; with --query and none given, CLIP weighs the positive against the "
                 "generic 'an underwater image', and the packaged encoder, which cannot read that phrase, scores the "
                 "positive alone (its probability)")
"""What a positive without a negative is scored against, as ``companion.vision.presampler`` does it."""


def add_topic_option(p: argparse.ArgumentParser, each: str = "each with its own summary") -> None:
    """``each``: what every topic gets from this command (a summary; a score per image for ``score``)."""
    p.add_argument("--topic", metavar="NAME=POSITIVE[;NEGATIVE...]", action="append", type=topic_option,
                   help=f"follow several topics at once, {each} (repeatable; replaces --query), "
                        "e.g. --topic 'fish=underwater image with fish;underwater image without fish'")


def add_summary_options(p: argparse.ArgumentParser, *, weights_help: str = "local CLIP checkpoint file") -> None:
    """The options of a summary run (K, queries, threshold, encoder, fps, enhancement, batch), for every command
    that summarizes a source (``summarize`` one, ``archive`` many): same names, same meaning."""
    p.add_argument("-k", "--k", type=int, help="summary size (default 6)")
    p.add_argument("--query", metavar="TEXT", help="positive query (default: 'underwater image with fish')")
    p.add_argument("--negative", metavar="TEXT", action="append", help=NEGATIVE_HELP)
    add_topic_option(p)
    p.add_argument("--threshold", type=float, metavar="TAU",
                   help="pre-sampling threshold tau_ss, a fraction (0.5) or a percentage (50); 0: no semantic gate")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="which encoder scores frames")
    p.add_argument("--model", help="open_clip architecture for --encoder clip (default ViT-B-32)")
    p.add_argument("--weights", metavar="PATH", help=weights_help)
    p.add_argument("--fps", type=float, help="frames per second kept from each source (default 5)")
    p.add_argument("--enhance", choices=["none", "always", "selective"], help="MERLION-E enhancement mode")
    p.add_argument("--batch", type=int, help="frames encoded together (default 8)")


def put_summary_options(over: Overrides, args: argparse.Namespace) -> None:
    """The options ``add_summary_options`` defines, those given, into ``over``."""
    put(over, "source", "fps", args.fps)
    put(over, "sampler", "k", args.k)
    put(over, "queries", "tau_ss", args.threshold)
    put(over, "enhance", "mode", args.enhance)
    put_queries_and_encoder(over, args)
