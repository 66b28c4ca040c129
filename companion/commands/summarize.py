"""``merlion summarize SOURCE --out DIR``: the K most informative frames of a video or image folder."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from companion.commands.overrides import Overrides, add_summary_options, put_summary_options

if TYPE_CHECKING:
    from companion.vision.summarize import SummaryRun


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
    for line in closing_lines(result):
        print(f"{result.out_dir}: {line}")
    return 0


def closing_lines(result: SummaryRun) -> list[str]:
    """What came out, each count in a unit it names: frames kept from a video (at the kept rate, which is what
    ``from N`` counts) and lost frames at the video's own rate; images of a folder."""
    from companion.vision.summarize import plural

    doc = result.document
    stats, topics = doc["params"]["stats"], doc["params"]["topics"]
    fps = doc["params"]["fps"]
    if result.stills:
        read = plural(result.frames_seen, "image")
    elif result.source_fps:
        read = f"{plural(result.frames_seen, 'frame')} read at {min(fps, result.source_fps):g} fps"
    else:
        read = plural(result.frames_seen, "frame")
    below = [t for t in topics if t["below_threshold"]]
    if result.frames_passed == 0 and below and len(topics) == 1:
        n = topics[0]["frames"]
        what = (f"nothing passed the query; the {plural(n, 'best frame')} {'is' if n == 1 else 'are'} kept, "
                f"marked below the threshold")
        notes = []  # said here already
    else:
        what = f"{result.frames_passed} passed the query"
        if below:
            what += f"; {sum(t['frames'] for t in below)} below the threshold, the best seen"
        notes = doc["params"]["short"]
    if stats.get("frames_skipped"):
        what += f"; {stats['frames_skipped']} skipped by the frame gate"
    lost = ""
    if result.frames_lost and result.stills:
        lost = f"; {plural(result.frames_lost, 'image')} could not be read"
    elif result.frames_lost and result.source_fps:
        lost = (f"; {plural(result.frames_lost, 'frame')} of the video at its own {result.source_fps:g} fps "
                f"({result.frames_lost / result.source_fps:.1f} s) could not be decoded")
    elif result.frames_lost:
        lost = f"; {plural(result.frames_lost, 'frame')} could not be decoded"
    sheets = ", ".join(t["contact_sheet"] for t in topics)
    frames = plural(len(doc["frames"]), "summary frame")
    return [f"{frames} from {read} ({what}){lost}; see summary.json and {sheets}", *notes]
