"""`merlion doctor`: check the camera, MAVLink, autopilot, encoder weights, CUDA, disk and config."""

from __future__ import annotations

import argparse
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager


def register(add_command) -> None:
    p = add_command("doctor", "check camera, MAVLink endpoint, autopilot heartbeat, encoder weights, CUDA, disk "
                    "space and the config; say how to fix what is wrong")
    p.add_argument("--config", metavar="FILE", help="the configuration to check (default: the built-in defaults)")
    p.add_argument("--wait", type=float, default=5.0, metavar="S", help="how long to wait for an autopilot "
                   "heartbeat (default 5)")
    p.add_argument("--signing-key", metavar="FILE", help="override mavlink.signing_key_file: check signing with this "
                   "key (32 raw bytes or a passphrase, as MAVProxy's signing setup; docs/security.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.commands.arg_checks import require_non_negative
    from companion.live.doctor import FAIL, run_checks

    require_non_negative("--wait", args.wait)
    if args.signing_key:  # a missing or empty key file is bad input, not a finding
        from vehicle.link.signing import load_key

        load_key(args.signing_key)
    overrides = {"mavlink": {"signing_key_file": args.signing_key}} if args.signing_key else None
    with logs_after_the_table():
        results = run_checks(args.config, dict(os.environ), heartbeat_wait_s=args.wait, overrides=overrides,
                             emit=lambda c: print(c.line(), flush=True))
    failed = [c for c in results if c.status == FAIL]
    print(f"merlion doctor: {len(failed)} problem(s)" if failed else "merlion doctor: all checks passed", flush=True)
    return 1 if failed else 0


class _Held(logging.Handler):
    """Keeps each distinct record once (level, logger, message), in the order first seen."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: dict[tuple[int, str, str], logging.LogRecord] = {}

    def emit(self, record: logging.LogRecord) -> None:
        self.records.setdefault((record.levelno, record.name, record.getMessage()), record)


@contextmanager
def logs_after_the_table() -> Iterator[None]:
    """The checks' log lines, each once, after the table instead of inside it: the autopilot and signing checks
    each open the link (its open line came twice), and a key mismatch logged its ERROR from both; the table's own
    line already says what it means, the log's is the detail."""
    root = logging.getLogger()
    shown, held = list(root.handlers), _Held()
    root.handlers = [held]
    try:
        yield
    finally:
        root.handlers = shown
        for record in held.records.values():
            if record.levelno >= root.getEffectiveLevel():
                for handler in shown:
                    handler.handle(record)
