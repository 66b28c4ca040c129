"""``merlion surface``: the topside receiver, gallery and live page."""

from __future__ import annotations

import argparse
import logging
import signal
import socket
import threading
from typing import TYPE_CHECKING

from companion.commands.arg_checks import require_positive, require_resolvable_host
from companion.commands.station_options import check_station_ids, companion_ids
from companion.errors import MerlionError

if TYPE_CHECKING:
    from companion.topside.tool import SurfaceOptions

log = logging.getLogger("merlion.surface")


def register(add_command) -> None:
    p = add_command("surface", "receive the companion's summary topside: gallery folder and optional live web page")
    p.add_argument("--connect", default="udpin:0.0.0.0:14550",
                   help="pymavlink connection string (default udpin:0.0.0.0:14550; beside QGroundControl use a "
                        "second routed port such as udpin:0.0.0.0:14560, see docs/surface-tool.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="gallery folder (created; reopened if it exists)")
    p.add_argument("--web", type=int, metavar="PORT", help="serve the live page on this port (0: any free port)")
    p.add_argument("--web-host", default="127.0.0.1", help="address the page listens on (default 127.0.0.1, this "
                   "machine only; 0.0.0.0 for every interface: changes still need the printed URL's token)")
    p.add_argument("--web-allow-host", action="append", default=[], metavar="NAME[:PORT]",
                   help="a further Host the page answers to (repeatable), e.g. a reverse proxy's name; besides "
                        "127.0.0.1, localhost and the --web-host address at the page's port")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (tests, demos)")
    p.add_argument("--companion", type=companion_ids, metavar="SYS:COMP",
                   help="the companion's ids (default: the camera component that sends captures)")
    p.add_argument("--system-id", type=int, default=254, help="this tool's MAVLink system id (default 254, never "
                                                             "255: that is the pilot's GCS)")
    p.add_argument("--component-id", type=int, default=190, help="this tool's MAVLink component id (default 190)")
    p.add_argument("--push-timeout", type=float, default=30.0, metavar="S",
                   help="fetch a capture's thumbnail by FTP when no push brought it within S seconds")
    p.add_argument("--no-ftp", action="store_true", help="never pull by MAVLink FTP (push only)")
    p.add_argument("--signing-key", metavar="FILE", help="MAVLink 2 signing key (32 raw bytes or a passphrase, as "
                   "MAVProxy's signing setup): sign what the tool sends (docs/security.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # the surface tool (pymavlink, cv2, numpy): 0.4-1.3 s measured, only for this command
    from companion.topside.tool import SurfaceOptions
    from companion.topside.web import check_web_port
    from vehicle.link.signing import load_key

    check_station_ids(args.system_id, args.component_id)
    require_positive("--duration", args.duration)
    require_positive("--push-timeout", args.push_timeout)
    require_resolvable_host("--connect", args.connect)
    check_port_free(args.connect)
    if args.web is not None:  # before the gallery folder is made or the link opened
        check_web_port(args.web, args.web_host)
    if args.signing_key:  # before the gallery folder is made
        load_key(args.signing_key)
    options = SurfaceOptions(connect=args.connect, system_id=args.system_id, component_id=args.component_id,
                             companion=args.companion, push_timeout_s=args.push_timeout, ftp=not args.no_ftp,
                             signing_key_file=args.signing_key)
    return serve(options, args.out, web_port=args.web, web_host=args.web_host, duration=args.duration,
                 web_allowed_hosts=args.web_allow_host)


def check_port_free(connect: str) -> None:
    from vehicle.link.endpoint import parse_connection  # pymavlink: 0.2-0.4 s measured, only for this command

    """A ``udpin`` port someone else holds (QGroundControl on 14550) would only get part of the traffic, or none:
    say so before starting, instead of a half-working tool."""
    endpoint = parse_connection(connect)
    if endpoint.scheme != "udpin":
        return
    host, _, port = endpoint.address.rpartition(":")
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind((host, int(port)))
    except OSError as err:
        raise MerlionError(f"--connect {connect}: UDP port {port} is taken ({err.strerror}); beside "
                           f"QGroundControl use a second routed port, e.g. udpin:0.0.0.0:14560 "
                           f"(docs/surface-tool.md)") from None
    finally:
        probe.close()


def serve(options: SurfaceOptions, out_dir: str, *, web_port: int | None = None, web_host: str = "127.0.0.1",
          duration: float | None = None, stop: threading.Event | None = None,
          web_allowed_hosts: list[str] | tuple[str, ...] = ()) -> int:
    """Run the surface tool until SIGINT/SIGTERM, ``stop``, or ``duration``; what tests and the demo call."""
    from companion.topside.actions import page_mark  # the surface tool: see run()
    from companion.topside.gallery import Gallery
    from companion.topside.tool import SurfaceTool
    from companion.topside.web import WebServer

    stop = stop or threading.Event()
    gallery = Gallery(out_dir)
    tool = SurfaceTool(options, gallery)
    web = None
    if web_port is not None:  # listening before the link opens: a port taken meanwhile stops nothing half-started
        web = WebServer(tool.snapshot, gallery.root, web_port, host=web_host, full_frame=tool.full_frame,
                        actions={"mark": lambda body: page_mark(tool.actions, body.get("index"), body.get("kind"))}, allowed_hosts=web_allowed_hosts)
        web.start()
    try:
        tool.open()
    except BaseException:
        if web is not None:
            web.close()
        raise
    if web is not None:
        # the line the demo and tests wait for (the port matters when 0 was asked)
        print(f"merlion surface: live page at {web.url}", flush=True)
    print(f"merlion surface: listening on {options.connect}, gallery in {gallery.root}", flush=True)
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        tool.run(stop, duration)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if web is not None:
            web.close()
    held = gallery.summary()
    names = [t.name for t in gallery.topics()]
    names += sorted({c.topic for c in held if c.topic and c.topic not in names})
    by_topic = (" (" + ", ".join(f"{name} {sum(c.topic == name for c in held)}" for name in names) + ")"
                if len(names) > 1 else "")  # several topics: how many frames each
    ignored = tool.status.unsigned_ignored
    unsigned = (f"; {ignored} unsigned messages ignored from "
                + ", ".join(f"{a}/{b}" for a, b in sorted(tool.status.unsigned_sources)) if ignored else "")
    print(f"merlion surface: {len(held)} frames in the summary{by_topic}, "
          f"{sum(1 for c in held if c.thumbnail)} with thumbnails, in {gallery.root}{unsigned}", flush=True)
    return 0
