"""A real nginx (Debian's) as BlueOS puts one in front of an extension: /extensionv2/<name>/ proxied to its port.

Started from the test with its own configuration in a temporary folder (no root paths, no daemon mode, a free
port), and a static folder at /cockpit/ standing for Cockpit's page, which embeds the widget in an iframe.
"""

from __future__ import annotations

import getpass
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.conftest import stop_process

CONF = """
daemon off;
user {user};
worker_processes 1;
pid {root}/nginx.pid;
error_log {root}/error.log warn;
events {{ worker_connections 64; }}
http {{
  access_log {root}/access.log;
  client_body_temp_path {root}/body; proxy_temp_path {root}/proxy; fastcgi_temp_path {root}/fastcgi;
  uwsgi_temp_path {root}/uwsgi; scgi_temp_path {root}/scgi;
  types {{ text/html html; application/javascript js; }}
  server {{
    listen 127.0.0.1:{port};
    location /extensionv2/{name}/ {{
      proxy_pass http://127.0.0.1:{upstream}/;
      proxy_set_header Host $http_host;
      proxy_http_version 1.1;
    }}
    location /cockpit/ {{ alias {root}/cockpit/; }}
  }}
}}
"""


def nginx_or_skip() -> str:
    for name in ("nginx", "/usr/sbin/nginx"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no nginx here and none could be installed (apt-get install nginx)")


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ReverseProxy:
    """nginx on a free port proxying ``/extensionv2/<name>/`` to ``upstream``; ``cockpit`` is its /cockpit/ folder."""

    def __init__(self, root: Path, upstream: int, name: str = "merlion") -> None:
        self.root = root
        self.cockpit = root / "cockpit"
        self.cockpit.mkdir(parents=True, exist_ok=True)
        self.port = free_tcp_port()
        conf = root / "nginx.conf"
        # workers run as this test's user, so they can read the test's private temporary folder
        conf.write_text(CONF.format(root=root, port=self.port, name=name, upstream=upstream, user=getpass.getuser()))
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
        return f"http://127.0.0.1:{self.port}"

    def close(self) -> None:
        stop_process(self.proc, 10)
