"""``merlion summarize SOURCE --out DIR``: the K most informative frames of a video or image folder."""

from __future__ import annotations

import argparse
from typing import Any

from companion.commands.overrides import Overrides, add_summary_options, put_summary_options


def register(add_command) -> None:
    p = add_command("summarize", "summarize a video file or image folder into DIR (summary.json, frames/, contact sheet)")
    p.add_argument("source", metavar="SOURCE", help="video file (H.264, HEVC, MJPEG, ...) or folder of images")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="output directory (must not exist unless --force)")
    add_summary_options(p)
    p.add_argument("--like", metavar="FILE", action="append", default=[],
                   help="an example of what is wanted (image or folder of images), repeatable")
    p.add_argument("--unlike", metavar="FILE", action="append", default=[],
                   help="an example of what is not wanted (image or folder of images), repeatable")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--force", action="store_true", help="replace DIR if it exists")
    p.add_argument("--explain", action="store_true", help="first say on stderr what each query resolves to")
    p.set_defaults(func=run)


def overrides_from(args: argparse.Namespace) -> dict[str, Any]:
    """Command-line options as a nested configuration override (only the ones given)."""
    over: Overrides = {"source": {"uri": args.source}}
    put_summary_options(over, args)
    return over


def run(args: argparse.Namespace) -> int:
    from companion.commands.query_source import blamed_queries, explained_config
    from companion.vision.summarize import summarize

    over = overrides_from(args)
    cfg = explained_config(args, over)
    with blamed_queries(cfg, config=args.config, overrides=over):
        result = summarize(cfg, args.out, force=args.force, like=args.like, unlike=args.unlike)
    lost = f", {result.frames_lost} lost" if result.frames_lost else ""
    sheets = ", ".join(t["contact_sheet"] for t in result.document["params"]["topics"])
    below = sum(f["below_threshold"] for f in result.document["frames"])
    below_text = f"; {below} below the threshold, the best seen" if below else ""
    print(f"{result.out_dir}: {len(result.document['frames'])} summary frames from {result.frames_seen} "
          f"({result.frames_passed} passed the query{lost}{below_text}); see summary.json and {sheets}")
    for note in result.document["params"]["short"]:
        print(f"{result.out_dir}: {note}")
    return 0
