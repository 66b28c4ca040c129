"""``merlion bench pipeline SOURCE``: end-to-end vs encoder-only and vs the paper's loop, sampler cost, peak RSS."""

from __future__ import annotations

import argparse
import json
import sys

from companion.commands.overrides import PRECISIONS


def register(add_command) -> None:
    p = add_command("pipeline", "vision pipeline speed: end to end vs encoder only, sampler cost, peak memory",
                    group="bench")
    p.add_argument("source", metavar="SOURCE",
                   help="video file or image folder, every frame at its native rate (looped until --frames are done)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="which encoder (default auto)")
    p.add_argument("--model", help="open_clip architecture for clip (default ViT-B-32)")
    p.add_argument("--weights", metavar="PATH", help="local CLIP checkpoint file")
    p.add_argument("--batch", type=int, help="frames encoded together (default 8)")
    p.add_argument("--precision", choices=PRECISIONS, help="encoder precision")
    p.add_argument("--runtime", choices=["torch", "onnx"], help="CLIP image tower runtime (default torch)")
    p.add_argument("--frames", type=int, default=256, help="frames to push through (default 256)")
    p.add_argument("--paper-frames", type=int, default=32,
                   help="frames for the paper's per-frame loop baseline (default 32; 0 skips it)")
    p.add_argument("--gate", choices=["none", "difference"], help="frame gate before the encoder (default: config)")
    p.add_argument("--gate-threshold", type=float, metavar="GREY", help="gate: mean absolute difference to encode")
    p.add_argument("--gate-max-gap", type=float, metavar="S", help="gate: encode at least every S seconds")
    p.add_argument("--fps", type=float, help="subsample the source to this rate (default: every frame)")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--json", action="store_true", help="end with one JSON object on the last line")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.bench.pipeline_bench import bench_pipeline
    from companion.config import load_config
    from companion.errors import UsageError

    if args.frames < 1:
        raise UsageError(f"--frames must be at least 1, got {args.frames}")
    if args.paper_frames < 0:
        raise UsageError(f"--paper-frames must be 0 or more, got {args.paper_frames}")
    over: dict = {"source": {"uri": args.source, "fps": args.fps if args.fps is not None else 240.0}}
    enc = {"name": args.encoder, "model": args.model, "weights": args.weights, "batch": args.batch,
           "precision": args.precision, "runtime": args.runtime}
    enc = {k: v for k, v in enc.items() if v is not None}
    if enc:
        over["encoder"] = enc
    gate = {"mode": args.gate, "threshold": args.gate_threshold, "max_gap_s": args.gate_max_gap}
    gate = {k: v for k, v in gate.items() if v is not None}
    if gate:
        over["gate"] = gate
    cfg = load_config(args.config, overrides=over)
    result = bench_pipeline(cfg, frames=args.frames, paper_frames=args.paper_frames,
                            progress=sys.stderr.isatty())
    print(result.table())
    if args.json:
        print(json.dumps(result.as_json()))
    return 0
