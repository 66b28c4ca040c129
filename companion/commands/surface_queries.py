"""``merlion surface-queries``: tell the companion which topics to follow (its text queries), from a shell."""

from __future__ import annotations

import argparse
import logging

from companion.commands.overrides import topic_option
from companion.commands.station_options import add_station_options, check_station_options
from companion.errors import MerlionError, UsageError


def register(add_command) -> None:
    p = add_command("surface-queries", "upload the text queries (one topic, or several at once) to the companion "
                    "over MAVLink FTP and print its answer")
    p.add_argument("file", nargs="?", metavar="FILE",
                   help="a queries file: the positive query, then its negatives, one per line; several topics each "
                        "start with a [name] line (docs/surface-tool.md)")
    p.add_argument("--query", metavar="TEXT", help="the positive query of one topic (instead of FILE)")
    p.add_argument("--negative", metavar="TEXT", action="append", default=[],
                   help="a negative query of that topic (repeatable, at least one)")
    p.add_argument("--topic", metavar="NAME=POSITIVE;NEGATIVE...", action="append", type=topic_option, default=[],
                   help="a topic to follow among several (repeatable), e.g. "
                        "--topic 'fish=underwater image with fish;underwater image without fish'")
    add_station_options(p, component_id=192)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # the link and its configuration (pymavlink, pydantic): 0.4 s measured, only for this command
    from companion.config import MavlinkConfig
    from companion.topside.queries_upload import queries_from_file, queries_from_options, upload_queries
    from vehicle.link.signing import load_key

    if args.file is not None and (args.query is not None or args.topic or args.negative):
        raise UsageError(f"surface-queries: give FILE ({args.file}) or --query/--topic, not both")
    check_station_options(args)
    if args.file is not None:
        data = queries_from_file(args.file)
    else:
        data = queries_from_options(args.query, args.negative, args.topic)
    if args.signing_key:
        load_key(args.signing_key)  # a bad key file is a one-line error before anything is sent
    cfg = MavlinkConfig(connection=args.connect, system_id=args.system_id, component_id=args.component_id,
                        signing_key_file=args.signing_key)
    system, component = args.companion
    logging.disable(logging.ERROR)  # the link reports its start and stop: our line says what matters, once
    try:
        answer = upload_queries(args.connect, cfg, args.companion, data, timeout=args.timeout)
    finally:
        logging.disable(logging.NOTSET)
    said = "; ".join(answer.status)
    if not answer.accepted:  # its status line says why; without one, the FTP error is all there is
        raise MerlionError(f"the companion {system}:{component} refused the queries: "
                           + (said or f"FTP {answer.error}, and no status line said why"))
    print(f"merlion surface-queries: {system}:{component} says: {said}" if said else
          f"merlion surface-queries: queries set on {system}:{component} (no status line heard)", flush=True)
    return 0
