"""A real nginx (Debian's) configured as BlueOS configures its own: the port-80 server with its server-level
``Access-Control-Allow-Origin *``, its frontend's locations (``blueos_facts.FRONTEND_LOCATIONS``: the
``~* \\.html$`` one takes any ``.html`` path, the extension's too), and the extension's location block exactly as
BlueOS's helper writes it (``blueos_facts.LOCATION_TEMPLATE``, included from an ``extensions/`` folder as nginx.conf
includes it).

It listens twice: on port 80 of a loopback address of its own (the test maps BlueOS's host names to it in
Chromium: an origin without a port, as on the vehicle) and on a free port of 127.0.0.1 (BlueOS reached on another
port: the Host it passes on has no port, the page's origin has one). A static folder at /cockpit/ (``^~``, so the
``.html`` location leaves it alone) stands for Cockpit's page,
which on a vehicle has a port of its own. Started from the test in a temporary folder: no root paths, no daemon
mode.
"""

from __future__ import annotations

import getpass
import os
import random
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.companion.extension.blueos_facts import FRONTEND_LOCATIONS, LOCATION_TEMPLATE, SERVER_HEADERS
from tests.conftest import stop_process

CONF = """
daemon off;
user {user};
worker_processes 1;
pid {root}/nginx.pid;
error_log {root}/error.log warn;
events {{ worker_connections 256; }}
http {{
  access_log {root}/access.log;
  client_body_temp_path {root}/body; proxy_temp_path {root}/proxy; fastcgi_temp_path {root}/fastcgi;
  uwsgi_temp_path {root}/uwsgi; scgi_temp_path {root}/scgi;
  types {{ text/html html; application/javascript js; }}
  server {{
    listen {vehicle}:{vehicle_port};
    listen 127.0.0.1:{port};
    {server_headers}
    {frontend}
    location ^~ /cockpit/ {{ alias {root}/cockpit/; }}
    include {root}/extensions/*.conf;
  }}
}}
"""


FRONTEND_PAGE = "<!doctype html><title>BlueOS</title>"
"""What BlueOS's frontend answers (its index.html stands in for the whole of it)."""


def nginx_or_skip() -> str:
    for name in ("nginx", "/usr/sbin/nginx"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no nginx here and none could be installed (apt-get install nginx)")


def free_tcp_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _loopback_address() -> str:
    """A 127.x.y.z of this run's own: port 80 there does not collide with other runs on this machine."""
    rng = random.Random(os.getpid() ^ time.monotonic_ns())
    return f"127.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}.{rng.randrange(2, 255)}"


class BlueOSProxy:
    """nginx as on the vehicle, proxying ``/extensionv2/<name>/`` to ``upstream``; ``cockpit`` is its /cockpit/."""

    def __init__(self, root: Path, name: str, upstream: int) -> None:
        self.root = root
        self.cockpit = root / "cockpit"
        self.cockpit.mkdir(parents=True, exist_ok=True)
        self.frontend = root / "frontend"
        self.frontend.mkdir(exist_ok=True)
        (self.frontend / "index.html").write_text(FRONTEND_PAGE)
        (root / "extensions").mkdir(exist_ok=True)
        self.location = LOCATION_TEMPLATE.format(name=name, port=upstream)
        (root / "extensions" / f"{name}.conf").write_text(self.location)
        self.vehicle = _loopback_address()
        self.vehicle_port = 80 if os.geteuid() == 0 else free_tcp_port(self.vehicle)  # port 80 needs root
        self.port = free_tcp_port()
        conf = root / "nginx.conf"
        # workers run as this test's user, so they can read the test's private temporary folder
        conf.write_text(CONF.format(root=root, port=self.port, vehicle=self.vehicle, vehicle_port=self.vehicle_port,
                                    server_headers="\n    ".join(SERVER_HEADERS), user=getpass.getuser(),
                                    frontend=FRONTEND_LOCATIONS.format(frontend=self.frontend)))
        self.proc = subprocess.Popen([nginx_or_skip(), "-c", str(conf), "-p", str(root)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 20
        while True:
            try:
                urllib.request.urlopen(f"{self.base}/cockpit/", timeout=2)
                break
            except urllib.error.HTTPError:
                break  # nginx answered (a 403/404 for the empty folder): it is up
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    err = self.proc.stderr.read().decode(errors="replace") if self.proc.poll() is not None else ""
                    raise AssertionError(f"nginx did not start: {err}") from None
                time.sleep(0.1)

    @property
    def base(self) -> str:
        """BlueOS reached on another port of 127.0.0.1."""
        return f"http://127.0.0.1:{self.port}"

    def vehicle_base(self, name: str) -> str:
        """BlueOS reached by ``name`` on port 80 (in Chromium, with ``resolver_rules``)."""
        return f"http://{name}" + ("" if self.vehicle_port == 80 else f":{self.vehicle_port}")

    def resolver_rules(self, *names: str) -> str:
        """Chromium's switch mapping ``names`` to the port-80 address (the rest stays as it is)."""
        return "--host-resolver-rules=" + ", ".join(f"MAP {n} {self.vehicle}" for n in names)

    def close(self) -> None:
        stop_process(self.proc, 10)
