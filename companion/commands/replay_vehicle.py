"""``merlion replay-vehicle``: play a recorded ArduSub telemetry log (.tlog) onto a MAVLink connection."""

from __future__ import annotations

import argparse
import json
import signal


def register(add_command) -> None:
    p = add_command("replay-vehicle", "replay a MAVLink telemetry log (.tlog) onto a connection at its recorded pace "
                    "(or --speed times faster), skipping bad-CRC records")
    p.add_argument("log", metavar="LOG.tlog", help="QGroundControl / MAVProxy telemetry log")
    p.add_argument("--connect", required=True, metavar="CONNECTION",
                   help="where to send, e.g. udpout:127.0.0.1:14551 (udpin:/tcpin: wait for a peer)")
    p.add_argument("--speed", type=float, default=1.0, metavar="X", help="X times the recorded pace (default 1)")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds of the log")
    p.add_argument("--duration", type=float, metavar="S", help="replay only S seconds of the log")
    p.add_argument("--include-gcs", action="store_true",
                   help="also replay the ground station's own messages (system 255); left out by default")
    p.add_argument("--wait-peer", type=float, default=30.0, metavar="S",
                   help="for udpin:/tcpin:, how long to wait for a peer before starting (default 30)")
    p.add_argument("--json", action="store_true", help="print the final counters as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.commands.arg_checks import require_non_negative, require_positive
    from companion.config import MavlinkConfig
    from companion.errors import MerlionError
    from vehicle.link.connection import MavLink
    from vehicle.link.endpoint import parse_connection
    from vehicle.sim.replay import TlogReplay, read_tlog

    require_positive("--speed", args.speed)
    require_positive("--duration", args.duration)
    require_non_negative("--start", args.start)
    require_non_negative("--wait-peer", args.wait_peer)
    endpoint = parse_connection(args.connect)
    next(iter(read_tlog(args.log)), None)  # a missing or foreign file fails here, before any socket opens
    # the link only carries the log's packets: no heartbeat of its own, and it never answers anything
    link = MavLink(args.connect, MavlinkConfig(system_id=1, component_id=1), name="replay", heartbeat=False)
    replay = TlogReplay(args.log, link, speed=args.speed, start_s=args.start, duration_s=args.duration,
                        include_gcs=args.include_gcs)
    signal.signal(signal.SIGTERM, lambda *_: replay.stop())
    link.start()
    try:
        if endpoint.scheme in ("udpin", "tcpin"):
            print(f"replay-vehicle: waiting for a peer on {args.connect}", flush=True)
            link.wait_open(5)
            if not _wait(lambda: link.connected, args.wait_peer):
                raise MerlionError(f"replay-vehicle: nobody connected to {args.connect} within {args.wait_peer:g} s")
        print(f"replay-vehicle: {args.log} -> {args.connect} at {args.speed:g}x", flush=True)
        stats = replay.run(progress=lambda s: print(
            f"replay-vehicle: {s.log_seconds:.0f} s of log, {s.sent} packets, {s.bytes} bytes", flush=True))
    finally:
        link.stop()
    counters = {"sent": stats.sent, "bytes": stats.bytes, "unsent": stats.unsent, "filtered_gcs": stats.filtered,
                "log_seconds": round(stats.log_seconds, 3), "wall_seconds": round(stats.wall_seconds, 3),
                "bad_crc": replay.log_stats.bad_crc, "resync_bytes": replay.log_stats.resync_bytes,
                "unknown": replay.log_stats.unknown}
    if args.json:
        print(json.dumps(counters), flush=True)
    else:
        print(f"replay-vehicle: sent {stats.sent} packets ({stats.bytes} bytes, {stats.log_seconds:.1f} s of log in "
              f"{stats.wall_seconds:.1f} s); skipped {replay.log_stats.bad_crc} bad-CRC records, "
              f"{stats.filtered} ground-station packets", flush=True)
    return 0


def _wait(predicate, timeout: float) -> bool:
    import time

    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True
