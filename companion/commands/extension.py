"""``merlion extension``: run as a BlueOS extension (the companion, its surface page, Cockpit's widget/actions)."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from companion import __version__
from companion.errors import UsageError
from companion.extension.metadata import PORT


def register(add_command) -> None:
    p = add_command("extension", "run as a BlueOS extension: the companion, its page for BlueOS's sidebar, "
                                 "/register_service and Cockpit's widget and actions")
    p.add_argument("--data", default="/usr/blueos/extensions/merlion", metavar="DIR",
                   help="store, gallery, log and optional merlion.yaml (BlueOS binds it; default %(default)s)")
    p.add_argument("--port", type=int, default=PORT,
                   help="the page's port (default %(default)s: none of BlueOS's services use it)")
    p.add_argument("--host", default="0.0.0.0", help="address the page listens on (default %(default)s)")
    p.add_argument("--router", metavar="HOST:PORT",
                   help="a UDP server endpoint of BlueOS's mavlink-router to join (e.g. 127.0.0.1:14660)")
    p.add_argument("--config", metavar="FILE", help="the companion's YAML configuration (default DIR/merlion.yaml)")
    p.add_argument("--source", metavar="SOURCE", help="camera (default: mavlink-camera-manager's RTSP stream)")
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                   help="a host name the page may be reached by, besides its IP addresses and BlueOS's names "
                        "(blueos.local, blueos-wifi.local, blueos-ethernet.local, blueos-hotspot.local, "
                        "companion.local; with or without .local)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="a web origin (SCHEME://HOST[:PORT]) whose pages may use the actions and JSON, with CORS "
                        "(e.g. Cockpit served over HTTP from the topside computer); adds to "
                        "extension.allowed_origins (default: none)")
    p.add_argument("--no-companion", action="store_true", help="serve the page only; start the companion later "
                                                                "from the widget or Cockpit")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (tests)")
    p.set_defaults(func=run)


def router_address(text: str | None) -> tuple[str, int] | None:
    if text is None:
        return None
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--router {text!r}: expected HOST:PORT (e.g. 127.0.0.1:14660)")
    return host, int(port)


def allowed_origins(given: list[str]) -> tuple[str, ...]:
    """``--allow-origin`` values as browsers send them; a malformed one is a usage error naming it."""
    try:
        from companion.config import web_origin  # pydantic: 0.15-0.25 s measured, only for this command

        return tuple(web_origin(text) for text in given)
    except ValueError as err:
        raise UsageError(f"--allow-origin {err}") from None


def run(args: argparse.Namespace) -> int:
    # imported here: the runner brings the surface tool and MAVLink (1.1 s measured with -X importtime), and the
    # guard pydantic through web_guard (0.15-0.25 s), which every other merlion command would pay at start-up
    from companion.extension.runner import ExtensionOptions, run_extension
    from companion.extension.vehicle_guard import vehicle_names

    if not 0 <= args.port < 65536:
        raise UsageError(f"--port {args.port}: not a TCP port")
    opts = ExtensionOptions(Path(args.data), port=args.port, host=args.host, router=router_address(args.router),
                            config=args.config, source=args.source,
                            allowed_hosts=vehicle_names(args.allow_host),
                            allowed_origins=allowed_origins(args.allow_origin), run_companion=not args.no_companion)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration is not None:
        timer = threading.Timer(args.duration, stop.set)
        timer.daemon = True
        timer.start()

    def ready(url: str, port: int) -> None:
        print(f"merlion extension: page at {url} (port {port})", flush=True)

    return run_extension(opts, __version__, stop, on_ready=ready)
