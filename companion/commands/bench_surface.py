"""``merlion bench surface``: surface-link payload efficiency and time for a summary to reach the surface; with
``--gallery``, what rewriting gallery.json at every cap costs the surface tool's receive loop."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path


def run_gallery(args: argparse.Namespace) -> int:
    from companion.bench import gallery_bench as gb

    with tempfile.TemporaryDirectory() as tmp:
        r = gb.measure_gallery(Path(tmp) / "gallery", seconds=args.gallery)
    print(f"gallery at every cap: {r['captures']} captures ({r['summary']} in the summary), {r['archived']} archived "
          f"of {r['dives']} dives, gallery.json {r['gallery_json_bytes'] / 1e6:.1f} MB, opened in {r['open_s']} s",
          flush=True)
    print(f"one change written through: {r['rewrite_s']} s on the caller", flush=True)
    print(f"receive loop, {r['loop_seconds']} s of changes at a 0.25 s throttle: {r['loop_changes']} changes "
          f"({r['changes_per_s']}/s of {r['rate']:.0f} asked), {r['rewrites']} rewrites; the loop spent "
          f"{r['loop_share_busy']:.1%} of its time in the gallery, {r['loop_share_writing']:.1%} in the calls that "
          f"rewrote gallery.json (worst {r['worst_stall_s']} s); last state on disk: {r['last_state_on_disk']} "
          f"(final flush {r['final_flush_s']} s)", flush=True)
    if args.json:
        print(json.dumps({"gallery": r}))
    return 0 if r["last_state_on_disk"] else 1


def run(args: argparse.Namespace) -> int:
    from companion.bench import surface_bench as sb
    from companion.errors import MerlionError

    if args.gallery:
        return run_gallery(args)
    try:
        images = sb.load_frames(args.source, args.frames)
    except ValueError as err:
        raise MerlionError(str(err)) from None
    print(f"surface bench: {args.frames} frames from {args.source}, budget {args.budget} B/s, "
          f"thumbnails <= {args.thumbnail_bytes} B", flush=True)
    push = sb.measure_push(images, budget=args.budget, thumbnail_bytes=args.thumbnail_bytes)
    result = {"push": push, "limit_encapsulated_data": round(sb.LIMIT, 4), "limit_reference": sb.REFERENCE_LIMIT}
    print(f"push: {push['frames']} thumbnails ({sum(push['thumbnail_bytes'])} B) reached the surface in "
          f"{push['seconds_to_surface']} s, intact={push['intact']}, captures {push['captures_received']}; "
          f"payload efficiency {push['push_efficiency']:.1%} of push bytes = {push['of_limit']:.1%} of the "
          f"ENCAPSULATED_DATA limit {sb.LIMIT:.2%} (253/267; {push['floor_for_these_sizes']:.1%} at best for these "
          f"sizes with handshake and marker), "
          f"{push['overall_efficiency']:.1%} of all bytes; {push['achieved_bytes_per_s']} B/s on the wire",
          flush=True)
    if not args.no_pull:
        with tempfile.TemporaryDirectory() as tmp:
            pull = sb.measure_pull(images, budget=args.budget, thumbnail_bytes=args.thumbnail_bytes,
                                   workdir=Path(tmp))
        result["pull"] = pull
        print(f"pull (mavftp): {pull['intact']}/{pull['frames']} thumbnails intact in {pull['seconds_to_surface']} s",
              flush=True)
    if args.window:
        win = sb.measure_window(images, budget=args.budget, thumbnail_bytes=args.thumbnail_bytes,
                                seconds=args.window)
        result["window"] = win
        print(f"budget: {win['windows']} windows of {win['window_s']:.0f} s while saturated: "
              f"{win['min_bytes_per_s']}-{win['max_bytes_per_s']} B/s on the wire for a {args.budget} B/s budget "
              f"({win['max_over_budget']:+.1%} at most)", flush=True)
    if args.json:
        print(json.dumps(result))
    return 0 if push["intact"] else 1


def register(add_command) -> None:
    p = add_command("surface", "surface link: payload efficiency and time for a summary to reach the surface",
                    group="bench")
    p.add_argument("--frames", type=int, default=6, help="summary size to send (default 6)")
    p.add_argument("--budget", type=int, default=2000, help="link budget in bytes/s (default 2000)")
    p.add_argument("--thumbnail-bytes", type=int, default=2500, help="thumbnail byte budget (default 2500)")
    p.add_argument("--source", default="synthetic://dive", help="frames from this source (default synthetic://dive)")
    p.add_argument("--no-pull", action="store_true", help="skip the MAVLink FTP download measurement")
    p.add_argument("--window", type=float, default=0, metavar="S",
                   help="also saturate the link for S seconds (>= 11) and report the wire rate over every 10 s window")
    p.add_argument("--gallery", type=float, default=0, metavar="S",
                   help="instead of the link: fill a gallery to every cap and run the receive loop's gallery.json "
                        "rewrites for S seconds")
    p.add_argument("--json", action="store_true", help="print the result as one JSON line at the end")
    p.set_defaults(func=run)
