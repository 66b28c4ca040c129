"""``merlion export STORE|SUMMARY --format fathomnet|coco|csv --out FILE``: the summary frames for science tools."""

from __future__ import annotations

import argparse

FORMAT_NAMES = ("fathomnet", "coco", "csv")


def register(add_command) -> None:
    p = add_command("export", "write the summary frames of a store, summary or campaign folder as FathomNet image "
                              "records, COCO or VIAME/DIVE CSV, with depth, pose, position and capture times")
    p.add_argument("source", metavar="STORE|SUMMARY", help="on-board store, summarize/archive dive folder, or "
                                                          "campaign folder")
    p.add_argument("--format", "-f", required=True, metavar="FORMAT", help=f"one of {', '.join(FORMAT_NAMES)}")
    p.add_argument("--out", "-o", required=True, metavar="FILE", help="file to write (replaced if it exists)")
    p.add_argument("--base-url", metavar="URL", help="fathomnet: where the images will be served (default: "
                                                      "their file:// URLs)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here: OpenCV and the formats (0.3 s measured with -X importtime), which every other merlion
    # command would pay at start-up
    from companion.export.writer import export

    records = export(args.source, args.format, args.out, args.base_url)
    dives = len({r.dive for r in records})
    placed = sum(r.lat is not None for r in records)
    print(f"{args.out}: {len(records)} frames from {dives} dive(s) as {args.format} ({placed} with a position)")
    return 0
