"""``merlion bench params``: the PARAM_SET -> PARAM_VALUE round trip a ground station sees, live companion running."""

from __future__ import annotations

import argparse
import json


def register(add_command) -> None:
    p = add_command("params", "PARAM_SET to PARAM_VALUE round trip at a ground station while the live companion "
                    "encodes a generated dive (simulated vehicle on a UDP hub): p50, p95, max",
                    group="bench")
    p.add_argument("--count", type=int, default=40, help="PARAM_SETs sent, one after another's echo (default 40)")
    p.add_argument("--encoder", default="visual", choices=["auto", "clip", "imagenet", "visual"])
    p.add_argument("--fps", type=float, default=5.0, help="frames/s of the generated camera (default 5)")
    p.add_argument("--json", action="store_true", help="last line: one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.bench.param_bench import run_param_bench  # the live companion: see commands/__init__.py
    from companion.commands.arg_checks import require_positive

    require_positive("--count", args.count)
    require_positive("--fps", args.fps)
    result = run_param_bench(args.count, encoder=args.encoder, fps=args.fps)
    print(f"PARAM_SET round trip ({result.encoder}, {result.frames_scored} frames scored): "
          f"{result.answered}/{result.count} answered, p50 {result.p50_ms} ms, p95 {result.p95_ms} ms, "
          f"max {result.max_ms} ms", flush=True)
    if args.json:
        print(json.dumps(result.to_dict()), flush=True)
    return 0 if result.answered == result.count else 1
