"""The options of a surface command that speaks to the companion as a MAVLink station of its own.

``surface-mark`` and ``surface-queries`` reach the companion the same way (a router endpoint, the companion's
ids, their own ids, a time limit, the signing key): one definition keeps their names, defaults and checks alike.
"""

from __future__ import annotations

import argparse

from companion.commands.arg_checks import require_positive
from companion.errors import UsageError


def check_station_ids(system_id: int, component_id: int) -> None:
    """The ids a surface command speaks with: never 255, the pilot's ground station (its failsafes and its
    parameter writes would be attributed to this tool)."""
    if not 1 <= system_id <= 254:
        raise UsageError(f"--system-id {system_id}: must be 1-254 (255 is the pilot's ground station)")
    if not 1 <= component_id <= 255:
        raise UsageError(f"--component-id {component_id}: must be 1-255")


def companion_ids(text: str) -> tuple[int, int]:
    """``--companion SYS:COMP`` (argparse type): the companion's system and component ids."""
    try:
        system, component = (int(p) for p in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SYSTEM:COMPONENT such as 1:100, got {text!r}") from None
    if not (1 <= system <= 255 and 1 <= component <= 255):
        raise argparse.ArgumentTypeError(f"ids must be 1-255, got {text!r}")
    return system, component


def add_station_options(p: argparse.ArgumentParser, *, component_id: int) -> None:
    """--connect, --companion, --system-id, --component-id (default ``component_id``: one per tool, so two
    tools are told apart), --timeout and --signing-key."""
    p.add_argument("--connect", default="udpout:127.0.0.1:14550",
                   help="pymavlink connection string to the vehicle's MAVLink router (default udpout:127.0.0.1:14550)")
    p.add_argument("--companion", type=companion_ids, default=(1, 100), metavar="SYS:COMP",
                   help="the companion's ids (default 1:100)")
    p.add_argument("--system-id", type=int, default=254, help="this tool's MAVLink system id (default 254)")
    p.add_argument("--component-id", type=int, default=component_id,
                   help=f"this tool's MAVLink component id (default {component_id})")
    p.add_argument("--timeout", type=float, default=15.0, metavar="S", help="give up after S seconds (default 15)")
    p.add_argument("--signing-key", metavar="FILE", help="MAVLink 2 signing key, as for merlion surface")


def check_station_options(args: argparse.Namespace) -> None:
    """What ``add_station_options`` defines, checked before anything is sent."""
    check_station_ids(args.system_id, args.component_id)
    require_positive("--timeout", args.timeout)
