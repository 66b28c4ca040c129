"""``merlion enhance IN OUT``: enhance an image, a video or a folder of images with the configured enhancer."""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING, Any

from companion.errors import UsageError

if TYPE_CHECKING:
    from companion.config import Config

log = logging.getLogger("merlion.enhance")


def add_enhancer_options(p: argparse.ArgumentParser) -> None:
    """The options every enhancement command shares: config file, method, model and its input contract."""
    p.add_argument("-c", "--config", metavar="FILE", help="YAML configuration (the enhance section is used)")
    p.add_argument("--method", choices=("classic", "model"), help="enhancer (default: enhance.method)")
    p.add_argument("--model", metavar="PATH", help="TorchScript (.pt) or ONNX (.onnx) model; implies --method model")
    p.add_argument("--input-size", metavar="WxH", help="model input size, e.g. 256x256 (enhance.model_input_size)")
    p.add_argument("--value-range", choices=("0-1", "-1-1", "0-255"), help="model value range")


def enhancer_config(args: argparse.Namespace) -> Config:
    """The configuration with the command-line options laid over the file's enhance section."""
    from companion.config import load_config  # pydantic: 0.15-0.25 s measured, not for every merlion call

    over: dict[str, Any] = {}
    if args.method:
        over["method"] = args.method
    if args.model:
        over["model_path"] = args.model
        over.setdefault("method", "model")
    if args.input_size:
        parts = args.input_size.lower().split("x")
        if len(parts) != 2 or not all(s.isdigit() for s in parts):
            raise UsageError(f"--input-size: {args.input_size!r} is not WIDTHxHEIGHT")
        over["model_input_size"] = [int(parts[0]), int(parts[1])]
    if args.value_range:
        over["model_value_range"] = args.value_range
    return load_config(args.config, overrides={"enhance": over} if over else None)


def run(args: argparse.Namespace) -> int:
    from companion.vision.enhancers.factory import make_enhancer
    from companion.vision.enhancers.files import enhance_path

    cfg = enhancer_config(args)
    enhancer = make_enhancer(cfg.enhance)
    report = enhance_path(enhancer, args.input, args.output, sbs=args.side_by_side)
    for path, why in report.failed:
        print(f"merlion: warning: {path}: {why}")
    print(f"enhanced {report.frames} frame(s) with {enhancer.name} into {args.output}")
    return 1 if report.failed else 0


def register(add_command) -> None:
    p = add_command("enhance", "enhance an image, video or folder of images (outputs keep the input names)")
    p.add_argument("input", metavar="IN", help="image, video file, or folder of images")
    p.add_argument("output", metavar="OUT", help="output file, or folder (created) for a folder input")
    add_enhancer_options(p)
    p.add_argument("--side-by-side", action="store_true", help="write raw and enhanced side by side")
    p.set_defaults(func=run)
