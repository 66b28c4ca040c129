"""The live page: a stdlib HTTP server in a thread, serving the static page, the gallery's thumbnails,
``/api/state`` (the JSON the page polls once a second; ``/state.js`` is the same as a script, what the page
loads first and what the offline copy in DIR holds) and ``/full/<n>.jpg`` (a summary frame at full resolution,
fetched from the vehicle over MAVLink FTP the first time it is asked for). Nothing to install topside beyond
this package.

It listens on 127.0.0.1 unless told otherwise. Reads (GET) stay open to whoever can reach the port; anything that
changes something is a POST to ``/api/<action>`` and needs the per-run token carried in the URL the tool prints
(``?token=``, or the ``X-Merlion-Token`` header; a full-frame fetch spends link bandwidth, so it needs it too), a Host that is an IP address or ``localhost`` (so a DNS
rebinding page cannot reach it by name) and, when the browser sends one, an Origin equal to the page's own.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import re
import secrets
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from companion.errors import MerlionError

log = logging.getLogger("merlion.surface.web")

STATIC = {"/": ("index.html", "text/html; charset=utf-8"), "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/app.js": ("app.js", "text/javascript; charset=utf-8")}
IMAGE_TYPES = {"jpg": "image/jpeg", "jpeg": "image/jpeg", "webp": "image/webp", "png": "image/png",
               "bmp": "image/bmp", "pgm": "image/x-portable-graymap"}
LOGS = {"gallery.json": "application/json", "log.csv": "text/csv; charset=utf-8"}
"""The gallery's tag logs, downloadable from the page."""
TOKEN_HEADER = "X-Merlion-Token"
MAX_BODY = 64 * 1024

FullFrame = Callable[[int], "Path | None"]
"""Image index -> the full frame's file once fetched, or None (trimmed meanwhile, or the link too slow)."""
_FULL = re.compile(r"/full/(\d+)\.jpg")

Action = Callable[[dict], dict]
"""A state-changing request: the JSON body in, a JSON answer out (a ValueError is a 400 with its message)."""


def _host_is_literal(host_header: str) -> bool:
    """An IP address or localhost: a browser only sends another name after a DNS rebinding trick."""
    host = urlsplit(f"//{host_header}").hostname or ""
    if host == "localhost":
        return True
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def refusal(headers, path: str, token: str) -> str | None:
    """Why a state-changing request must be refused (None: it may go ahead)."""
    host = headers.get("Host", "")
    if not _host_is_literal(host):
        return f"Host {host!r} is not an address"
    origin = headers.get("Origin")
    if origin is not None and origin != f"http://{host}":
        return f"cross-origin request from {origin!r}"
    if headers.get("Sec-Fetch-Site") not in (None, "same-origin", "none"):
        return "cross-site request"
    given = parse_qs(urlsplit(path).query).get("token", [""])[0] or headers.get(TOKEN_HEADER, "")
    if not hmac.compare_digest(given.encode(), token.encode()):
        return "missing or wrong token"
    return None


def _make_handler(state: Callable[[], dict], gallery_dir: Path, token: str,
                  actions: dict[str, Action], full_frame: FullFrame | None = None) -> type[BaseHTTPRequestHandler]:
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
                why = refusal(self.headers, self.path, token)
                if why is not None:
                    log.warning("web: refused %s from %s: %s", path, self.client_address[0], why)
                    self._send(why.encode(), "text/plain", HTTPStatus.FORBIDDEN)
                    return
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

        def do_POST(self) -> None:  # noqa: N802 (http.server's name)
            why = refusal(self.headers, self.path, token)
            if why is not None:
                log.warning("web: refused POST %s from %s: %s", self.path.split("?", 1)[0], self.client_address[0],
                            why)
                self._json({"error": why}, HTTPStatus.FORBIDDEN)
                return
            path = self.path.split("?", 1)[0]
            action = actions.get(path.removeprefix("/api/")) if path.startswith("/api/") else None
            if action is None:
                self._json({"error": "no such action"}, HTTPStatus.NOT_FOUND)
                return
            length = int(self.headers.get("Content-Length") or 0)
            if not 0 <= length <= MAX_BODY:
                self._json({"error": "body too large"}, HTTPStatus.REQUEST_ENTITY_TOO_LARGE)
                return
            try:
                body = json.loads(self.rfile.read(length) or b"{}")
                if not isinstance(body, dict):
                    raise ValueError("expected a JSON object")
                self._json(action(body))
            except ValueError as err:
                self._json({"error": str(err)}, HTTPStatus.BAD_REQUEST)

        def _json(self, doc: dict, status: HTTPStatus = HTTPStatus.OK) -> None:
            self._send(json.dumps(doc).encode(), "application/json", status)

    return Handler


class WebServer:
    """Serves the live page on ``host:port`` until ``close``; port 0 picks a free one (see ``port``).

    ``actions`` are the page's state-changing requests (POST /api/<name>) and ``full_frame`` fetches a frame over
    the link (GET /full/<n>.jpg); both are guarded by ``token`` (new each run)."""

    def __init__(self, state: Callable[[], dict], gallery_dir: str | Path, port: int, host: str = "127.0.0.1",
                 actions: dict[str, Action] | None = None, *, full_frame: FullFrame | None = None) -> None:
        self.token = secrets.token_urlsafe(18)
        self.host = host
        handler = _make_handler(state, Path(gallery_dir), self.token, dict(actions or {}), full_frame)
        try:
            self._server = ThreadingHTTPServer((host, port), handler)
        except OSError as err:
            raise MerlionError(f"--web {port}: cannot listen on {host}:{port} ({err.strerror})") from None
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name="surface-web", daemon=True)

    @property
    def url(self) -> str:
        """The page's address with the token, as the tool prints it (the loopback address for a wildcard bind)."""
        shown = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        shown = f"[{shown}]" if ":" in shown else shown
        return f"http://{shown}:{self.port}/?token={self.token}"

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
