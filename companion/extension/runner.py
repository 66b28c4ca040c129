"""``merlion extension``: what the BlueOS extension's container runs.

One process owns three things: a small UDP hub (the container's own router: the companion, the surface tool and the
topic switch all join it, and it forwards to and from BlueOS's mavlink-router endpoint), the companion itself as a
child process (``merlion run``, which the widget and Cockpit can stop and start again) and the surface tool with its
page, served on ``--port`` for BlueOS's sidebar and Cockpit. The store, the gallery and the companion's log live in
the data folder, which BlueOS binds from /usr/blueos/extensions/merlion, so they survive an update of the image.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

from companion.config import TopicConfig, load_config
from companion.errors import UsageError
from companion.extension.actions import extension_actions
from companion.extension.metadata import PORT
from companion.extension.pages import extension_pages
from companion.extension.vehicle_guard import VehicleGuard, vehicle_names
from companion.live.udp_hub import UdpHub
from companion.topside.gallery import Gallery
from companion.topside.tool import SurfaceOptions, SurfaceTool
from companion.topside.web import WebServer

log = logging.getLogger("merlion.extension")

DEFAULT_SOURCE = "rtsp://127.0.0.1:8554/video_stream__dev_video2"
"""mavlink-camera-manager's RTSP stream of the BlueROV2's camera: BlueOS owns /dev/video* unless the user frees it."""


@dataclass
class ExtensionOptions:
    data_dir: Path
    port: int = PORT
    host: str = "0.0.0.0"
    """BlueOS's helper scans the vehicle's ports on all addresses."""
    router: tuple[str, int] | None = None
    """A UDP endpoint of BlueOS's mavlink-router (e.g. a "UDP Server" on 127.0.0.1:14660) the hub joins."""
    config: str | None = None
    source: str | None = None
    allowed_hosts: tuple[str, ...] = vehicle_names()
    """Host names of the vehicle (BlueOS's beacon's, and ``--allow-host``); its IP addresses come on top."""
    allowed_origins: tuple[str, ...] = ()
    """Web origins trusted with CORS besides the configuration's ``extension.allowed_origins`` (``--allow-origin``)."""
    run_companion: bool = True
    companion_args: list[str] = field(default_factory=list)
    """More ``merlion run`` options (tests: --duration, a synthetic source)."""


class CompanionProcess:
    """``merlion run`` as a child process joined to the hub; start and stop are idempotent and thread-safe."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str] | None = None) -> None:
        self.argv = argv
        self.log_path = log_path
        self.env = {**os.environ, **(env or {})}
        self._proc: subprocess.Popen | None = None
        self._lock = threading.Lock()

    @property
    def running(self) -> bool:
        with self._lock:
            return self._proc is not None and self._proc.poll() is None

    def start(self) -> None:
        with self._lock:
            if self._proc is not None and self._proc.poll() is None:
                return
            with open(self.log_path, "ab") as out:
                self._proc = subprocess.Popen(self.argv, stdout=out, stderr=subprocess.STDOUT, env=self.env)
            log.info("companion started (pid %d), log in %s", self._proc.pid, self.log_path)

    def stop(self, timeout: float = 30.0) -> None:
        """SIGTERM, so the companion stops cleanly with its store saved; killed only if it does not."""
        with self._lock:
            proc, self._proc = self._proc, None
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        log.info("companion stopped (exit %s)", proc.returncode)


def run_extension(opts: ExtensionOptions, version: str, stop: threading.Event,
                  on_ready=None) -> int:
    """Serve until ``stop``; ``on_ready(url)`` once the page listens (the command prints it)."""
    data = opts.data_dir
    try:
        data.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"--data {data}: cannot create it ({err.strerror})") from None
    config = opts.config or (str(data / "merlion.yaml") if (data / "merlion.yaml").is_file() else None)
    cfg = load_config(config)  # a bad config file is one line and exit 2, before anything starts
    topics: list[TopicConfig] = list(cfg.queries.topic_list())  # what the widget and Cockpit may switch to
    origins = tuple(dict.fromkeys((*cfg.extension.allowed_origins, *opts.allowed_origins)))
    if origins:
        log.info("CORS granted to %s", ", ".join(origins))
    hub = UdpHub(outputs=[opts.router] if opts.router else None).start()
    argv = [sys.executable, "-m", "companion", "run", "--mavlink", hub.url, "--store", str(data / "store")]
    argv += ["--config", config] if config else []
    argv += ["--source", opts.source or DEFAULT_SOURCE] if (opts.source or not config) else []
    # without a configuration of the user's, the surface may upload marks and topics (what the widget and Cockpit's
    # actions do); a user's merlion.yaml decides for itself (surface.ftp_writable)
    companion = CompanionProcess(argv + opts.companion_args, data / "companion.log",
                                 env=None if config else {"MERLION__SURFACE__FTP_WRITABLE": "true"})
    key = cfg.mavlink.signing_key_file  # the companion's: with it the page and the topic switch sign and accept
    tool = SurfaceTool(SurfaceOptions(connect=hub.url, system_id=254, component_id=190, signing_key_file=key),
                       Gallery(data / "gallery"))  # only signed messages (the surface tool's --signing-key)

    def status() -> dict:
        return {"supervised": True, "companion_running": companion.running, "topics": [t.name for t in topics],
                "pid": os.getpid()}

    web = None
    try:
        tool.open()
        # the Host check takes the names; an address (the vehicle's, at any time) passes it as any address does
        guard = VehicleGuard(opts.allowed_hosts, frozenset(origins))
        pages = extension_pages(version=version, topics=[t.name for t in topics], status=status,
                                frame_ancestors=guard.frame_ancestors)
        web = WebServer(tool.snapshot, tool.gallery.root, opts.port, host=opts.host, full_frame=tool.full_frame,
                        actions=extension_actions(tool, connect=hub.url, topics=topics, companion=companion,
                                                  signing_key_file=key),
                        allowed_hosts=opts.allowed_hosts, pages=pages, guard=guard, allowed_origins=origins)
        web.start()
        if opts.run_companion:
            companion.start()
        if on_ready is not None:
            on_ready(f"http://127.0.0.1:{web.port}/", web.port)
        tool.run(stop, None)
    finally:
        companion.stop()
        if web is not None:
            web.close()
        tool.close()
        hub.stop()
    return 0
