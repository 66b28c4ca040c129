"""`merlion bench soak`: the live companion for N minutes at a speed-up; fps, drops, RSS growth, latency."""

from __future__ import annotations

import argparse
import json
import sys


def register(add_command) -> None:
    p = add_command("soak", "run the live companion (simulated vehicle, generated dive at a speed-up) for N "
                    "minutes: frames/s, dropped frames, peak RSS and growth, capture-to-surface latency",
                    group="bench")
    p.add_argument("--minutes", type=float, default=5.0, help="length of the run (default 5)")
    p.add_argument("--fps", type=float, default=15.0, help="frames/s the generated camera delivers (default 15, "
                   "three times the vehicle's 5)")
    p.add_argument("--encoder", default="auto", choices=["auto", "clip", "imagenet", "visual"])
    p.add_argument("--gate", choices=["none", "difference"],
                   help="frame gate (default: the configuration's); none to compare with the encoder's rate")
    p.add_argument("--duration", type=float, metavar="S", help="length of the run in seconds (instead of --minutes)")
    p.add_argument("--clip", type=clip_size, metavar="WxH",
                   help="render the generated dive to an H.264 file of this size at --fps first and play that, "
                        "looped (a camera's stream at its resolution, decode included), e.g. --clip 1920x1080 "
                        "--fps 60; also measures the file's decode rate")
    p.add_argument("--json", action="store_true", help="last line: one JSON object with every figure")
    p.set_defaults(func=run)


def clip_size(text: str) -> tuple[int, int]:
    """``WxH`` (argparse type), each side 32-4096 as the generated dive allows."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 1920x1080, got {text!r}") from None
    if not (32 <= w <= 4096 and 32 <= h <= 4096) or w % 2 or h % 2:
        raise argparse.ArgumentTypeError(f"{text!r}: each side even and in 32-4096")
    return w, h


def run(args: argparse.Namespace) -> int:
    from companion.bench.soak_bench import run_soak, summary_dict
    from companion.commands.arg_checks import require_positive

    require_positive("--minutes", args.minutes)
    if args.duration is not None:
        require_positive("--duration", args.duration)
        args.minutes = args.duration / 60.0
    require_positive("--fps", args.fps)
    last = [-1]

    def progress(elapsed: float, total: float, status: str) -> None:
        if int(elapsed) // 30 != last[0]:  # a line every 30 s: long runs show they are alive
            last[0] = int(elapsed) // 30
            print(f"soak {elapsed:5.0f}/{total:.0f} s: {status}", file=sys.stderr, flush=True)

    result = run_soak(args.minutes, encoder=args.encoder, fps=args.fps, progress=progress, gate=args.gate,
                      clip_size=args.clip)
    d = summary_dict(result)
    camera = "generated camera" if d["source"] == "synthetic" else f"generated dive from a {d['source']}"
    print(f"encoder           {d['encoder']}, {camera} at {d['source_fps']:g} fps, {d['minutes']:g} min")
    print(f"frames            seen {d['frames_seen']}, scored {d['frames_scored']} ({d['scored_fps']} /s), "
          f"skipped by the gate ({d['gate']}) {d['frames_skipped']}, dropped at the input {d['frames_dropped']} "
          f"({d['dropped_pct']:g}% of seen; {d['dropped_after_warmup']} after the {d['warmup_s']:g}-s warm-up)")
    if d["decode_fps"] is not None:
        print(f"decode            {d['decode_fps']} frames/s flat out, {d['decode_vs_source']:g} x the source's "
              f"{d['source_fps']:g} fps (at ~1 or below the run is decode bound)")
    if d["admit_ms"] is not None:
        print(f"capture thread    gate and downscale {d['admit_ms']:g} ms/frame, off the inference thread")
    ratio = "-" if d["scored_vs_encoder"] is None else f"{d['scored_vs_encoder']:.2f}"
    print(f"encoder           {d['encoder_fps']} frames/s inside the encoder during the run: scored/s is {ratio} x "
          "that")
    print("stages            " + ", ".join(f"{k} {v:g}" for k, v in d["stage_ms"].items()) + " ms/frame")
    print(f"summary           {d['summary_added']} frames added; {d['captures_received']} captures at the surface")
    print(f"memory            peak RSS {d['peak_rss_mb']} MB; {d['rss_after_warmup_mb']} MB after {d['warmup_s']:g} s "
          f"warm-up -> {d['rss_end_mb']} MB at the end: growth {d['rss_growth_pct']}% (target <= 5%)")
    print(f"latency           capture -> CAMERA_IMAGE_CAPTURED p50 {d['latency_p50_s']} s, p95 {d['latency_p95_s']} s")
    if args.json:
        print(json.dumps(d))
    return 0
