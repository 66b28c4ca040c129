"""``merlion telemetry``: connect to the vehicle as the companion does and show depth, attitude and mode."""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading


def register(add_command) -> None:
    p = add_command("telemetry", "connect to the vehicle (or sim-vehicle / replay-vehicle) and print the telemetry "
                    "the companion sees: depth and its source, attitude, heading, mode, battery, rates")
    p.add_argument("--connect", metavar="CONNECTION", help="override mavlink.connection, e.g. udpin:0.0.0.0:14551 "
                   "or tcp:127.0.0.1:5777")
    p.add_argument("--config", metavar="FILE", help="YAML configuration (mavlink and telemetry sections are used)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--no-rates", action="store_true", help="do not ask the autopilot for message rates (listen only)")
    p.add_argument("--json", action="store_true", help="print the final state and counters as JSON")
    p.add_argument("--signing-key", metavar="FILE", help="override mavlink.signing_key_file: MAVLink 2 signing key "
                   "(32 raw bytes or a passphrase, as MAVProxy's signing setup; docs/security.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.commands.arg_checks import require_positive, require_resolvable_host
    from companion.config import load_config
    from companion.errors import UsageError
    from vehicle.autopilot.telemetry_watch import watch_telemetry

    require_positive("--duration", args.duration)
    overrides = {"mavlink": {"connection": args.connect}} if args.connect else {}
    if args.signing_key:
        overrides.setdefault("mavlink", {})["signing_key_file"] = args.signing_key
    cfg = load_config(args.config, overrides=overrides, environ=dict(os.environ))
    if not cfg.mavlink.connection:
        raise UsageError("mavlink.connection is null: give --connect")
    require_resolvable_host("--connect" if args.connect else "mavlink.connection", cfg.mavlink.connection)
    if cfg.mavlink.signing_key_file:
        from vehicle.link.signing import load_key

        load_key(cfg.mavlink.signing_key_file)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    print(f"telemetry: {cfg.mavlink.connection} as component {cfg.mavlink.component_id}", flush=True)
    result = watch_telemetry(cfg.mavlink, cfg.telemetry, duration=args.duration, stop=stop, request_rates=not args.no_rates,
                             report=None if args.json else lambda line: print(f"telemetry: {line}", flush=True))
    if args.json:
        print(json.dumps(result, default=str), flush=True)
    if not result["messages"]:  # nothing to show is a failed check, not a quiet success
        from companion.errors import MerlionError

        raise MerlionError(f"{cfg.mavlink.connection}: nothing heard from an autopilot in "
                           f"{result['listened_s']:.0f} s (is the vehicle, its router or sim-vehicle sending there?)")
    return 0
