"""``merlion surface-mark``: tell the companion "more like this" / "not this" about summary frames, from a shell."""

from __future__ import annotations

import argparse
import logging

from companion.commands.station_options import add_station_options, check_station_options
from companion.errors import UsageError


def register(add_command) -> None:
    p = add_command("surface-mark", "send the operator's marks (image indices of summary frames) to the companion: "
                    "later frames are kept by the query and the marked examples together")
    p.add_argument("--like", type=int, action="append", default=[], metavar="INDEX",
                   help="image index of a frame to find more of (repeatable)")
    p.add_argument("--unlike", type=int, action="append", default=[], metavar="INDEX",
                   help="image index of a frame not wanted (repeatable)")
    p.add_argument("--clear", action="store_true", help="remove every mark (score by the query alone)")
    add_station_options(p, component_id=191)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # the link and its configuration (pymavlink, pydantic): 0.4 s measured, only for this command
    from companion.config import MavlinkConfig
    from companion.topside.marks_upload import upload_marks
    from vehicle.link.signing import load_key

    if not args.like and not args.unlike and not args.clear:
        raise UsageError("surface-mark: give --like INDEX and/or --unlike INDEX, or --clear")
    if args.clear and (args.like or args.unlike):
        raise UsageError("surface-mark: --clear takes no --like/--unlike")
    bad = [i for i in args.like + args.unlike if i < 0]
    if bad:
        raise UsageError(f"surface-mark: image index {bad[0]} is negative")
    check_station_options(args)
    if args.signing_key:
        load_key(args.signing_key)  # a bad key file is a one-line error before anything is sent
    cfg = MavlinkConfig(connection=args.connect, system_id=args.system_id, component_id=args.component_id,
                        signing_key_file=args.signing_key)
    logging.disable(logging.ERROR)  # the link reports its start and stop: our line says what matters, once
    try:
        upload_marks(args.connect, cfg, args.companion, args.like, args.unlike, timeout=args.timeout)
    finally:
        logging.disable(logging.NOTSET)
    print(f"merlion surface-mark: marks set on {args.companion[0]}:{args.companion[1]}: "
          f"like {args.like}, unlike {args.unlike}", flush=True)
    return 0
