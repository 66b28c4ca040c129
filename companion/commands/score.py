"""``merlion score PATH...``: the semantic score of each image, one line per image (or JSON lines)."""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from typing import Any

from companion.commands.overrides import (
    NEGATIVE_HELP,
    PRECISIONS,
    Overrides,
    add_topic_option,
    put_queries_and_encoder,
)


def register(add_command) -> None:
    p = add_command("score", "score images (files or folders) against the queries: one line per image")
    p.add_argument("paths", metavar="PATH", nargs="+", help="image files or folders of images")
    p.add_argument("--query", metavar="TEXT", help="positive query (default: 'underwater image with fish')")
    p.add_argument("--negative", metavar="TEXT", action="append", help=NEGATIVE_HELP)
    add_topic_option(p, "each image scored against each (the highest first, then one score per topic)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="which encoder scores images")
    p.add_argument("--model", help="open_clip architecture for --encoder clip (default ViT-B-32)")
    p.add_argument("--weights", metavar="PATH", help="local CLIP checkpoint file (or open_clip model folder)")
    p.add_argument("--pretrained", metavar="TAG", help="open_clip pretrained tag, used if already cached")
    p.add_argument("--precision", choices=PRECISIONS, help="encoder precision")
    p.add_argument("--batch", type=int, help="images encoded together (default 8)")
    p.add_argument("--like", metavar="FILE", action="append", default=[],
                   help="an example of what is wanted (image or folder of images), repeatable")
    p.add_argument("--unlike", metavar="FILE", action="append", default=[],
                   help="an example of what is not wanted (image or folder of images), repeatable")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--dive", action="store_true",
                   help="the images are one dive's frames, in order: each is also judged against the ones before it "
                        "(the packaged encoder's scene head; default: each image on its own)")
    p.add_argument("--json", action="store_true", help='JSON lines: {"file": ..., "score": ...}')
    p.add_argument("--explain", action="store_true", help="first say on stderr what each query resolves to")
    p.set_defaults(func=run)


def overrides_from(args: argparse.Namespace) -> dict[str, Any]:
    """Only the options given, as a nested configuration override."""
    over: Overrides = {}
    put_queries_and_encoder(over, args)
    return over


def run(args: argparse.Namespace) -> int:
    from companion.commands.query_source import blamed_queries, explained_config
    from companion.vision.progress_lines import ProgressLines
    from companion.vision.score_images import score_images

    over = overrides_from(args)
    cfg = explained_config(args, over)
    with blamed_queries(cfg, config=args.config, overrides=over):
        scored = score_images(cfg, args.paths, like=args.like, unlike=args.unlike, dive=args.dive)
        first = next(scored, None)  # the queries are read before the first image is scored
    failed = scored_any = 0
    # on a terminal the scores themselves show the progress; in a log, a line now and then says it is working
    lines = None if sys.stderr.isatty() else ProgressLines("score", "image", None)
    for item in itertools.chain([first] if first is not None else [], scored):
        if item.score is None:
            failed += 1
            print(f"merlion: error: {item.file}: {item.error}", file=sys.stderr)
            continue
        if lines is not None:  # images scored (an unreadable one has its own line above)
            lines.set_postfix(**({"unreadable": failed} if failed else {}))
            lines.update(1)
        scored_any = 1
        several = len(item.topics) > 1
        if args.json:
            row: dict[str, Any] = {"file": str(item.file), "score": round(item.score, 6)}
            if several:
                row["topics"] = {name: round(v, 6) for name, v in item.topics.items()}
            print(json.dumps(row), flush=True)
        elif several:  # the highest first, then each topic's
            each = "\t".join(f"{name}={v:.4f}" for name, v in item.topics.items())
            print(f"{item.file}\t{item.score:.4f}\t{each}", flush=True)
        else:
            print(f"{item.file}\t{item.score:.4f}", flush=True)
    # README's rule: nothing could be read is bad input (2, as for every command); some could, the work ran and
    # part of it failed (1)
    return 0 if not failed else 1 if scored_any else 2
