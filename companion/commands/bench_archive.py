"""``merlion bench archive [VIDEO]``: videos per minute of ``merlion archive`` with 1 and 2 (or more) workers."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

DEFAULT_VIDEO = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "survey" / "survey_480x270.mp4"


def register(add_command) -> None:
    p = add_command("archive", "merlion archive scaling: videos per minute with 1 and 2 local Ray workers",
                    group="bench")
    p.add_argument("video", nargs="?", metavar="VIDEO",
                   help=f"video to cut the clips from (default {DEFAULT_VIDEO})")
    p.add_argument("--videos", type=int, default=8, help="clips per run (default 8)")
    p.add_argument("--seconds", type=float, default=4.0, help="length of each clip (default 4 s)")
    p.add_argument("--workers", type=int, action="append", help="worker counts to compare (default 1 and 2)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], default="imagenet",
                   help="encoder (default imagenet, the packaged EfficientNet-Lite0)")
    p.add_argument("--fps", type=float, help="frames per second kept from each clip (default 5)")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--json", action="store_true", help="end with one JSON object on the last line")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.bench.archive_bench import bench_archive
    from companion.config import load_config
    from companion.errors import UsageError

    if args.videos < 1 or args.seconds <= 0:
        raise UsageError(f"--videos must be at least 1 and --seconds more than 0, got {args.videos}, {args.seconds}")
    workers = args.workers or [1, 2]
    if any(w < 1 for w in workers):
        raise UsageError(f"--workers must be at least 1, got {workers}")
    video = Path(args.video) if args.video else DEFAULT_VIDEO
    if not video.is_file():
        raise UsageError(f"{video}: no such video")
    over: dict = {"encoder": {"name": args.encoder}}
    if args.fps is not None:
        over["source"] = {"fps": args.fps}
    cfg = load_config(args.config, overrides=over)
    result = bench_archive(cfg, video, videos=args.videos, seconds=args.seconds, workers=sorted(workers))
    print(result.table())
    if args.json:
        print(json.dumps(result.as_json()))
    return 0
