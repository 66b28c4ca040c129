"""The live page: a stdlib HTTP server in a thread, serving the static page, the gallery's thumbnails,
``/api/state`` (the JSON the page polls once a second; ``/state.js`` is the same as a script, what the page
loads first and what the offline copy in DIR holds) and ``/full/<n>.jpg`` (a summary frame at full resolution,
fetched from the vehicle over MAVLink FTP the first time it is asked for). Nothing to install topside beyond
this package."""

from __future__ import annotations

import json
import logging
import re
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path

from companion.errors import MerlionError

log = logging.getLogger("merlion.surface.web")

STATIC = {"/": ("index.html", "text/html; charset=utf-8"), "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/app.js": ("app.js", "text/javascript; charset=utf-8")}
IMAGE_TYPES = {"jpg": "image/jpeg", "jpeg": "image/jpeg", "webp": "image/webp", "png": "image/png",
               "bmp": "image/bmp", "pgm": "image/x-portable-graymap"}
LOGS = {"gallery.json": "application/json", "log.csv": "text/csv; charset=utf-8"}
"""The gallery's tag logs, downloadable from the page."""


FullFrame = Callable[[int], "Path | None"]
"""Image index -> the full frame's file once fetched, or None (trimmed meanwhile, or the link too slow)."""
_FULL = re.compile(r"/full/(\d+)\.jpg")


def _make_handler(state: Callable[[], dict], gallery_dir: Path,
                  full_frame: FullFrame | None = None) -> type[BaseHTTPRequestHandler]:
    root = gallery_dir.resolve()

    class Handler(BaseHTTPRequestHandler):
        server_version = "merlion-surface"

        def log_message(self, fmt: str, *args) -> None:  # quiet: the page polls every second
            log.debug("web: " + fmt, *args)

        def _send(self, body: bytes, ctype: str, status: HTTPStatus = HTTPStatus.OK) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            path = self.path.split("?", 1)[0]
            if path in STATIC:
                name, ctype = STATIC[path]
                body = resources.files("companion.topside").joinpath("static", name).read_bytes()
                self._send(body, ctype)
            elif path == "/api/state":
                self._send(json.dumps(state()).encode(), "application/json")
            elif path == "/state.js":
                self._send(b"window.MERLION_STATE = " + json.dumps(state()).encode() + b";\n",
                           "text/javascript; charset=utf-8")
            elif (match := _FULL.fullmatch(path)) and full_frame is not None:
                found = full_frame(int(match.group(1)))  # blocks this request's thread while FTP fetches it
                if found is None:
                    self._send(b"full frame not available", "text/plain", HTTPStatus.NOT_FOUND)
                else:
                    self._send(found.read_bytes(), "image/jpeg")
            elif path.startswith("/files/"):
                name = path[len("/files/"):]
                target = (root / name).resolve()
                ext = target.suffix.lstrip(".").lower()
                ctype = LOGS.get(name) or IMAGE_TYPES.get(ext)
                if ctype is None or not target.is_relative_to(root) or not target.is_file():
                    self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)
                    return
                self._send(target.read_bytes(), ctype)
            else:
                self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)

    return Handler


class WebServer:
    """Serves the live page on ``host:port`` until ``close``; port 0 picks a free one (see ``port``)."""

    def __init__(self, state: Callable[[], dict], gallery_dir: str | Path, port: int, host: str = "0.0.0.0",
                 *, full_frame: FullFrame | None = None) -> None:
        try:
            self._server = ThreadingHTTPServer((host, port), _make_handler(state, Path(gallery_dir), full_frame))
        except OSError as err:
            raise MerlionError(f"--web {port}: cannot listen on {host}:{port} ({err.strerror})") from None
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name="surface-web", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
