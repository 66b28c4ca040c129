"""`merlion run`: the live companion (camera -> MERLION pipeline -> store + MAVLink surface link)."""

from __future__ import annotations

import argparse
import os


def register(add_command) -> None:
    p = add_command("run", "run the live companion: camera, pipeline, on-board store, MAVLink surface link")
    p.add_argument("--config", metavar="FILE", help="YAML configuration (default: the built-in defaults)")
    p.add_argument("--mavlink", metavar="CONNECTION", help="override mavlink.connection (e.g. udpin:0.0.0.0:14551, "
                   "tcp:127.0.0.1:5777; 'none' for no vehicle link)")
    p.add_argument("--source", metavar="SOURCE", help="override source.uri (file, folder, /dev/video0, rtsp://, "
                   "udp://@:5600, synthetic://dive)")
    p.add_argument("--store", metavar="DIR", help="override store.dir")
    p.add_argument("--loop", action="store_true", help="start a file or folder source again when it ends")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (tests, trials)")
    p.add_argument("--signing-key", metavar="FILE", help="override mavlink.signing_key_file: MAVLink 2 signing key "
                   "(32 raw bytes or a passphrase, as MAVProxy's signing setup; docs/security.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.commands.arg_checks import require_positive
    from companion.commands.query_source import blamed_queries
    from companion.live.runner import build, cli_overrides, run_companion

    require_positive("--duration", args.duration)
    overrides = cli_overrides(source=args.source, mavlink=args.mavlink, store=args.store, loop=args.loop)
    if args.signing_key:
        overrides.setdefault("mavlink", {})["signing_key_file"] = args.signing_key
    cfg = build(args.config, overrides, os.environ)
    if cfg.mavlink.signing_key_file:  # a bad key is a one-line error before the camera or the encoder start
        from vehicle.link.signing import LinkSigning

        LinkSigning.from_settings(cfg.mavlink, name="companion")
    with blamed_queries(cfg, config=args.config, overrides=overrides):
        report = run_companion(cfg, environ=os.environ, duration=args.duration)
    store = report["store"]
    mode = f"memory-only ({store.get('reason')})" if store.get("memory_only") else "on disk"
    signing = report.get("signing", {})
    if signing.get("enabled"):
        print(f"merlion run: signing on; refused {signing['rejected']} unsigned or badly signed writes "
              f"{signing['rejected_by_source']}", flush=True)
    if signing.get("mismatch"):
        print(f"merlion run: the autopilot {signing['autopilot']}: it ignored everything this companion sent "
              "(docs/security.md)", flush=True)
    print(f"merlion run: seen {report['frames_seen']}, passed {report['frames_passed']}, "
          f"dropped {report['frames_dropped']}, summary {report['summary']}, sent {report['bytes_sent']} bytes, "
          f"bad MAVLink {report['rx_bad']}, store {store.get('dir')} {mode}", flush=True)
    return 0
