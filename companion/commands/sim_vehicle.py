"""``merlion sim-vehicle``: a simulated ArduSub on the wire, for demos and tests without a vehicle."""

from __future__ import annotations

import argparse
import json
import math
import signal
import threading


def register(add_command) -> None:
    p = add_command("sim-vehicle", "simulated ArduSub autopilot on MAVLink: scripted dive, telemetry, rate commands, "
                    "silence and reboot on demand (SIGUSR1: go silent, SIGUSR2: reboot)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--connect", metavar="CONNECTION", help="send to the companion, e.g. udpout:127.0.0.1:14551")
    where.add_argument("--listen", metavar="CONNECTION", help="wait for the companion, e.g. udpin:0.0.0.0:14552 "
                       "or tcpin:127.0.0.1:5760")
    p.add_argument("--profile", metavar="YAML", help="dive profile (default: descend to 8 m, 4-lane survey, ascend)")
    p.add_argument("--system-id", type=int, default=1, help="the vehicle's MAVLink system id (default 1)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until Ctrl-C)")
    p.add_argument("--silence-at", type=float, metavar="T", help="go silent T seconds after start")
    p.add_argument("--silence-for", type=float, default=5.0, metavar="N",
                   help="how long a silence lasts (also for SIGUSR1), seconds (default 5)")
    p.add_argument("--reboot-at", type=float, metavar="T", help="reboot T seconds after start (boot time restarts)")
    p.add_argument("--reboot-s", type=float, default=2.0, metavar="S", help="silent time of a reboot (default 2)")
    p.add_argument("--rate", action="append", default=[], metavar="MESSAGE=HZ",
                   help="default rate of a message, e.g. ATTITUDE=20 or ATTITUDE_QUATERNION=10 (repeatable)")
    p.add_argument("--no-message-interval", action="store_true",
                   help="behave like old firmware: answer SET_MESSAGE_INTERVAL with UNSUPPORTED")
    p.add_argument("--fluid-density", type=float, default=1025.0, help="kg/m^3 for SCALED_PRESSURE2 (default 1025)")
    p.add_argument("--pilot-timeout", type=float, default=3.0, metavar="S",
                   help="FS_PILOT_TIMEOUT: disarm when MANUAL_CONTROL stops this long while armed (default 3)")
    p.add_argument("--gcs-timeout", type=float, default=5.0, metavar="S",
                   help="FS_GCS_TIMEOUT: GCS failsafe when MAV_GCS_SYSID's (255) heartbeats stop this long (default 5)")
    p.add_argument("--gcs-failsafe", choices=["off", "warn", "disarm", "depth_hold", "surface"], default="disarm",
                   help="FS_GCS_ENABLE action, 0-4 (default disarm, the firmware's 2); a ground station may also "
                   "change it, and the timeouts, with PARAM_SET")
    p.add_argument("--json", action="store_true", help="print the final counters as JSON")
    p.add_argument("--signing-key", metavar="FILE", help="sign like ArduSub with this key (32 raw bytes or a "
                   "passphrase): unsigned parameter writes and commands are then ignored (docs/security.md)")
    p.set_defaults(func=run)


def _rates(items: list[str]) -> dict[str, float]:
    from companion.errors import UsageError
    from vehicle.sim.vehicle import DEFAULT_RATES

    rates: dict[str, float] = {}
    for item in items:
        name, _, hz = item.partition("=")
        name = name.strip().upper()
        if name not in DEFAULT_RATES:
            raise UsageError(f"--rate {item}: unknown message (one of {', '.join(DEFAULT_RATES)})")
        try:
            rates[name] = float(hz)
        except ValueError:
            raise UsageError(f"--rate {item}: rate must be a number of Hz") from None
        if not (math.isfinite(rates[name]) and rates[name] >= 0):
            raise UsageError(f"--rate {item}: rate must be >= 0")
    return rates


def run(args: argparse.Namespace) -> int:
    from companion.commands.arg_checks import require_non_negative, require_positive
    from companion.errors import UsageError
    from vehicle.link.endpoint import parse_connection
    from vehicle.sim.dive_profile import load_profile
    from vehicle.sim.vehicle import SimVehicle, run_sim_vehicle

    connection = args.connect or args.listen
    parse_connection(connection)
    if not 1 <= args.system_id <= 254:
        raise UsageError(f"--system-id {args.system_id}: must be 1-254 (255 is the ground station's)")
    for name in ("duration", "silence_for", "reboot_s", "fluid_density", "pilot_timeout", "gcs_timeout"):
        require_positive(f"--{name.replace('_', '-')}", getattr(args, name))
    for name in ("silence_at", "reboot_at"):
        require_non_negative(f"--{name.replace('_', '-')}", getattr(args, name))
    sim = SimVehicle(connection, load_profile(args.profile), system_id=args.system_id, rates=_rates(args.rate),
                     message_interval=not args.no_message_interval, fluid_density=args.fluid_density,
                     reboot_s=args.reboot_s, pilot_timeout_s=args.pilot_timeout, gcs_timeout_s=args.gcs_timeout,
                     gcs_failsafe=args.gcs_failsafe, signing_key_file=args.signing_key)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGUSR1, lambda *_: sim.silence(args.silence_for))
    signal.signal(signal.SIGUSR2, lambda *_: sim.reboot())
    print(f"sim-vehicle: ArduSub system {args.system_id} on {connection}{' (signed)' if args.signing_key else ''} "
          f"(dive {sim.profile.duration:.0f} s; SIGUSR1: silent {args.silence_for:g} s, SIGUSR2: reboot)", flush=True)
    result = run_sim_vehicle(sim, duration=args.duration, silence_at=args.silence_at, silence_for=args.silence_for,
                             reboot_at=args.reboot_at, stop=stop, report=lambda line: print(line, flush=True))
    if args.json:
        print(json.dumps(result), flush=True)
    else:
        print(f"sim-vehicle: sent {sum(result['sent'].values())} messages, {result['commands']} commands answered, "
              f"{result['reboots']} reboots, failsafes: {', '.join(result['failsafes']) or 'none'}", flush=True)
    return 0
