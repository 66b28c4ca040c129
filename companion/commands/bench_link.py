"""``merlion bench link``: telemetry the MAVLink link can take (log replay at rising speed) and pose lookup cost;
with ``--clients N``: the on-board link under N ground stations at once (corrupted packets, receive-loop stall);
with ``--flood S``: what a signed ground station still receives during an unsigned flood (captures, thumbnails)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def register(add_command) -> None:
    p = add_command("link", "MAVLink receive capacity (a tlog replayed at rising speeds) and pose_at cost; "
                    "--clients N: corrupted packets and receive-loop stalls with N ground stations at once",
                    group="bench")
    p.add_argument("log", metavar="LOG.tlog", nargs="?",
                   help="telemetry log to replay (e.g. ../shared/data/ardusub/surface_small.tlog); "
                        "not needed with --clients")
    p.add_argument("--speeds", default="5,20,50", help="comma-separated replay speeds (default 5,20,50)")
    p.add_argument("--start", type=float, default=30.0, help="log second to start at (default 30)")
    p.add_argument("--duration", type=float, default=30.0,
                   help="log seconds per speed; with --clients, seconds of load per client count (default 30)")
    p.add_argument("--clients", metavar="N[,N...]",
                   help="stress the on-board link with N ground-station processes at once (e.g. 1,2,4): FTP "
                        "lists and downloads, parameter sets, refused uploads, with a simulated vehicle")
    p.add_argument("--flood", metavar="S", type=float,
                   help="an unsigned flood (parameter, FTP and command requests, heartbeats, garbage) beside a "
                        "signed ground station, signing on: S seconds without it, S with it, S after it; captures "
                        "and thumbnail chunks received in each (e.g. 60)")
    p.add_argument("--flood-rate", metavar="N", type=float, default=1500.0,
                   help="flood datagrams per second (default 1500)")
    p.add_argument("--flood-ids", metavar="N", type=int, default=200,
                   help="made-up unsigned system ids the flood comes from (default 200)")
    p.add_argument("--live", action="store_true",
                   help="with --flood: flood the whole live companion instead (merlion run on a video file, "
                        "merlion sim-vehicle and a signed ground station behind a router, one signing key): S "
                        "seconds without it, S with it, S/2 after it")
    p.add_argument("--json", action="store_true", help="last line: one JSON object")
    p.set_defaults(func=run)


def _counts(text: str) -> list[int]:
    from companion.errors import UsageError

    try:
        counts = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise UsageError(f"--clients {text}: expected whole numbers like 1,2,4") from None
    if not counts or not all(1 <= n <= 16 for n in counts):
        raise UsageError(f"--clients {text}: client counts must be between 1 and 16")
    return counts


def run(args: argparse.Namespace) -> int:
    from companion.errors import UsageError

    if not math.isfinite(args.duration) or args.duration <= 0:
        raise UsageError(f"--duration {args.duration}: must be a positive number of seconds")
    if args.flood is not None:
        return _flood(args)
    if args.live:
        raise UsageError("bench link: --live goes with --flood S")
    if args.clients is not None:
        from vehicle.sim.link_bench import stress

        results = [stress(n, args.duration, report=lambda line: print(line, flush=True))
                   for n in _counts(args.clients)]
        if args.json:
            print(json.dumps({"stress": results}), flush=True)
        return 0
    if args.log is None:
        raise UsageError("bench link: give a LOG.tlog to replay, or --clients N")
    from vehicle.sim.link_bench import run_link_bench
    from vehicle.sim.replay import read_tlog

    try:
        speeds = [float(s) for s in args.speeds.split(",") if s.strip()]
    except ValueError:
        raise UsageError(f"--speeds {args.speeds}: expected numbers like 5,20,50") from None
    if not speeds or not all(math.isfinite(s) and s > 0 for s in speeds):
        raise UsageError(f"--speeds {args.speeds}: speeds must be positive")
    next(iter(read_tlog(args.log)), None)
    result = run_link_bench(Path(args.log), speeds, start_s=args.start, duration_s=args.duration,
                            report=lambda line: print(line, flush=True))
    if args.json:
        print(json.dumps(result), flush=True)
    return 0


def _flood(args: argparse.Namespace) -> int:
    from companion.errors import UsageError

    if not math.isfinite(args.flood) or not 5 <= args.flood <= 600:
        raise UsageError(f"--flood {args.flood}: seconds per phase must be between 5 and 600")
    if not math.isfinite(args.flood_rate) or not 1 <= args.flood_rate <= 20000:
        raise UsageError(f"--flood-rate {args.flood_rate}: datagrams per second must be between 1 and 20000")
    if not 1 <= args.flood_ids <= 240:
        raise UsageError(f"--flood-ids {args.flood_ids}: must be between 1 and 240 (system ids 10-249)")
    if args.live:
        from companion.bench.flood_live_bench import measure_live_flood

        result = measure_live_flood(args.flood, rate=args.flood_rate, ids=args.flood_ids,
                                    report=lambda line: print(line, flush=True))
        if args.json:
            print(json.dumps({"live_flood": result}), flush=True)
        return 0
    from vehicle.sim.flood_bench import measure_flood

    result = measure_flood(args.flood, rate=args.flood_rate, ids=args.flood_ids,
                           report=lambda line: print(line, flush=True))
    if args.json:
        print(json.dumps({"flood": result}), flush=True)
    return 0
