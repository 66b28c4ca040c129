"""``merlion bench link``: telemetry the MAVLink link can take (log replay at rising speed) and pose lookup cost."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def register(add_command) -> None:
    p = add_command("link", "MAVLink receive capacity (a tlog replayed at rising speeds) and pose_at cost",
                    group="bench")
    p.add_argument("log", metavar="LOG.tlog", help="telemetry log to replay (e.g. ../shared/data/ardusub/surface_small.tlog)")
    p.add_argument("--speeds", default="5,20,50", help="comma-separated replay speeds (default 5,20,50)")
    p.add_argument("--start", type=float, default=30.0, help="log second to start at (default 30)")
    p.add_argument("--duration", type=float, default=30.0, help="log seconds per speed (default 30)")
    p.add_argument("--json", action="store_true", help="last line: one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.errors import UsageError
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
