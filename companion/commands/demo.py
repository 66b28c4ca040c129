"""`merlion demo`: simulated ArduSub + companion + surface tool on loopback, in one command (the README's first)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(add_command) -> None:
    p = add_command("demo", "run the whole system on this machine: simulated ArduSub, the companion on a generated "
                    "dive, and the surface tool; prints a report")
    p.add_argument("--duration", type=float, default=60.0, metavar="S", help="seconds to run (default 60)")
    p.add_argument("--out", type=Path, default=Path("merlion-demo"), metavar="DIR",
                   help="where the surface gallery (DIR/surface), store (DIR/store) and report go "
                        "(default ./merlion-demo; an earlier run there is moved aside to DIR.previous-TIME)")
    p.add_argument("--resume", action="store_true", help="continue the earlier run's store and gallery in DIR "
                   "instead of starting fresh")
    p.add_argument("--source", metavar="PATH", help="real video or a folder of frames instead of the generated dive "
                   "(played in a loop)")
    p.add_argument("--tau-ss", type=float, metavar="T", help="semantic threshold (default: the config's, 0.5)")
    p.add_argument("--encoder", default="auto", choices=["auto", "clip", "imagenet", "visual"],
                   help="encoder (default auto: CLIP when its weights are here, else the packaged one)")
    p.add_argument("--web", type=int, default=0, metavar="PORT",
                   help="serve the surface page on this port of 127.0.0.1 (default 0: a free port; the URL is "
                        "printed at the start)")
    p.add_argument("--signing-key", metavar="FILE", help="sign every link of the demo with this key (32 raw bytes or "
                   "a passphrase; docs/security.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging

    from companion.commands.arg_checks import require_positive
    from companion.live.demo import DemoOptions, main

    require_positive("--duration", args.duration)
    from companion.topside.web import check_web_port

    check_web_port(args.web, "127.0.0.1")  # a page port in use stops the demo before anything starts or moves
    if not args.verbose:  # the demo prints its own progress; warnings (e.g. the encoder fallback) still show
        logging.getLogger().setLevel(logging.WARNING)
    return main(DemoOptions(out=args.out, duration=args.duration, source=args.source, tau_ss=args.tau_ss,
                            encoder=args.encoder, web_port=args.web, signing_key=args.signing_key, resume=args.resume))
