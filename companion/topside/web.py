"""The live page: a stdlib HTTP server in a thread, serving the static page, the gallery's thumbnails,
``/api/state`` (the JSON the page polls once a second; ``/state.js`` is the same as a script, what the page
loads first and what the offline copy in DIR holds) and ``/full/<n>.jpg`` (a summary frame at full resolution,
fetched from the vehicle over MAVLink FTP the first time it is asked for). Nothing to install topside beyond
this package.

It listens on 127.0.0.1 unless told otherwise. Every request needs a Host this server answers to, and everything
but the page itself goes only to same-origin requests (``web_guard``: no other web origin reads the state, no DNS
rebinding). Anything that changes something is a POST to ``/api/<action>`` and also needs the per-run token carried
in the URL the tool prints (``?token=``, or the ``X-Merlion-Token`` header; a full-frame fetch spends link
bandwidth, so it needs it too): the surface tool's ``TokenGuard``; a host of the page may bring its own ``Guard``
(the BlueOS extension's needs no secret, ``companion/extension/vehicle_guard``). Clients cannot pin the server
(``http_bounds``: bounded threads, read deadlines, bounded head and path), and bad input is a clean 4xx, never a
traceback.
"""

from __future__ import annotations

import errno
import json
import logging
import re
import secrets
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from importlib import resources
from pathlib import Path

from companion.errors import UsageError
from companion.topside.http_bounds import MAX_JSON_DEPTH, BoundedHandler, BoundedHTTPServer, json_too_deep
from companion.topside.web_guard import (
    TOKEN_HEADER,
    Guard,
    HostPolicy,
    TokenGuard,
    trusted_origin,
    unnamed_include,
)

__all__ = ["TOKEN_HEADER", "Pages", "WebServer"]

log = logging.getLogger("merlion.surface.web")

STATIC = {"/": ("index.html", "text/html; charset=utf-8"), "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/app.js": ("app.js", "text/javascript; charset=utf-8")}
IMAGE_TYPES = {"jpg": "image/jpeg", "jpeg": "image/jpeg", "webp": "image/webp", "png": "image/png",
               "bmp": "image/bmp", "pgm": "image/x-portable-graymap"}
LOGS = {"gallery.json": "application/json", "log.csv": "text/csv; charset=utf-8"}
"""The gallery's tag logs, downloadable from the page."""
MAX_BODY = 64 * 1024
MAX_PATH = 2048

FullFrame = Callable[[int], "Path | None"]
"""Image index -> the full frame's file once fetched, or None (trimmed meanwhile, or the link too slow)."""
_FULL = re.compile(r"/full/(\d+)\.jpg")
PREFLIGHT_MAX_AGE_S = 600
"""How long a browser may reuse a granted CORS preflight."""

Action = Callable[[dict], dict]
"""A state-changing request: the JSON body in, a JSON answer out (a ValueError is a 400 with its message)."""


@dataclass(frozen=True)
class Pages:
    """What a host of the page adds (the BlueOS extension, companion/extension/): more GET routes (path -> a function
    of the request's path and query giving the body and its content type, looked up before the page's own), and
    which of them are pages like the page itself (no state in them: served whatever the origin), and headers sent
    with every answer (the extension's ``Content-Security-Policy: frame-ancestors``)."""

    routes: dict[str, Callable[[str], tuple[bytes, str]]] = field(default_factory=dict)
    open_paths: frozenset[str] = frozenset()
    headers: dict[str, str | Callable[[], str]] = field(default_factory=dict)
    """A value may be a function, asked for each answer (the vehicle's addresses change while it runs)."""


def _make_handler(state: Callable[[], dict], gallery_dir: Path, guard: Guard, hosts: HostPolicy,
                  actions: dict[str, Action], full_frame: FullFrame | None = None,
                  pages: Pages | None = None, trusted: frozenset[str] = frozenset()) -> type[BoundedHandler]:
    root = gallery_dir.resolve()
    pages = pages or Pages()

    class Handler(BoundedHandler):
        server_version = "merlion-surface"

        def log_message(self, fmt: str, *args) -> None:  # quiet: the page polls every second
            log.debug("web: " + fmt, *args)

        def _send(self, body: bytes, ctype: str, status: HTTPStatus = HTTPStatus.OK) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            for name, value in pages.headers.items():
                self.send_header(name, value() if callable(value) else value)
            self._cors_headers()
            self.end_headers()
            self.wfile.write(body)

        def _cors_headers(self) -> None:
            """For a trusted origin only (none by default): let that page read the answer."""
            if not trusted:
                return
            origin = trusted_origin(self.headers, trusted)
            if origin is not None:
                self.send_header("Access-Control-Allow-Origin", origin)
            self.send_header("Vary", "Origin")

        def _refuse(self, why: str) -> None:
            log.warning("web: refused %s %s from %s: %s", self.command, self.path.split("?", 1)[0][:100],
                        self.client_address[0], why)
            self._send(why.encode(), "text/plain; charset=utf-8", HTTPStatus.FORBIDDEN)

        def _guard(self, *, page: bool) -> bool:
            """True when the request may go on: a Host we answer to, and (but for the page) the same origin."""
            self.request_read()
            if len(self.path) > MAX_PATH:
                self.send_error(HTTPStatus.REQUEST_URI_TOO_LONG, "path too long")
                return False
            host = self.headers.get("Host", "")
            if not hosts.allows(host):
                self._refuse(f"Host {host[:100]!r} is not this server")
                return False
            why = None if page else guard.read_refusal(self.headers)
            if why is not None:
                self._refuse(why)
                return False
            return True

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            path = self.path.split("?", 1)[0]
            if not self._guard(page=path in STATIC or path in pages.open_paths):
                return
            try:
                self._get(path)
            except OSError as err:  # a name the filesystem refuses (too long, bad bytes): not found
                log.debug("web: GET %s: %s", path[:100], err)
                self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)

        def _get(self, path: str) -> None:
            if path in pages.routes:
                self._send(*pages.routes[path](self.path))
            elif path in STATIC:
                name, ctype = STATIC[path]
                body = resources.files("companion.topside").joinpath("static", name).read_bytes()
                self._send(body, ctype)
            elif path == "/api/state":
                self._send(json.dumps(state()).encode(), "application/json")
            elif path == "/state.js":
                why = unnamed_include(self.headers)  # a script runs in whatever page includes it
                if why is not None:
                    self._refuse(why)
                    return
                self._send(b"window.MERLION_STATE = " + json.dumps(state()).encode() + b";\n",
                           "text/javascript; charset=utf-8")
            elif (match := _FULL.fullmatch(path)) and full_frame is not None:
                why = guard.fetch_refusal(self.headers, self.path)
                if why is not None:
                    self._refuse(why)
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
            if len(self.path) > MAX_PATH:
                self.request_read()
                self.send_error(HTTPStatus.REQUEST_URI_TOO_LONG, "path too long")
                return
            host = self.headers.get("Host", "")
            why = (f"Host {host[:100]!r} is not this server" if not hosts.allows(host)
                   else guard.change_refusal(self.headers, self.path))
            if why is not None:
                self.request_read()
                log.warning("web: refused POST %s from %s: %s", self.path.split("?", 1)[0][:100],
                            self.client_address[0], why)
                self._json({"error": why}, HTTPStatus.FORBIDDEN)
                return
            path = self.path.split("?", 1)[0]
            action = actions.get(path.removeprefix("/api/")) if path.startswith("/api/") else None
            if action is None:
                self.request_read()
                self._json({"error": "no such action"}, HTTPStatus.NOT_FOUND)
                return
            given = (self.headers.get("Content-Length") or "0").strip()
            if not given.isascii() or not given.isdigit():
                self.request_read()
                self._json({"error": f"bad Content-Length {given[:40]!r}"}, HTTPStatus.BAD_REQUEST)
                return
            length = int(given)
            if length > MAX_BODY:
                self.request_read()
                self._json({"error": "body too large"}, HTTPStatus.REQUEST_ENTITY_TOO_LARGE)
                return
            self.rfile.allow(length)
            raw = self.rfile.read(length)
            self.request_read()
            if len(raw) < length:
                self.close_connection = True
                return  # the client went away, or was cut for being too slow: nobody to answer
            if json_too_deep(raw):
                self._json({"error": f"JSON nested deeper than {MAX_JSON_DEPTH} levels"}, HTTPStatus.BAD_REQUEST)
                return
            try:
                body = json.loads(raw or b"{}")
                if not isinstance(body, dict):
                    raise ValueError("expected a JSON object")
                self._json(action(body))
            except (ValueError, TypeError) as err:  # a field of the wrong type ({"topic": []}) is bad input too
                self._json({"error": str(err)}, HTTPStatus.BAD_REQUEST)

        def _json(self, doc: dict, status: HTTPStatus = HTTPStatus.OK) -> None:
            self._send(json.dumps(doc).encode(), "application/json", status)

    if not trusted:
        return Handler  # no OPTIONS at all (501, as http.server answers a method it lacks)

    class CorsHandler(Handler):
        def do_OPTIONS(self) -> None:  # noqa: N802 (http.server's name)
            """A CORS preflight: granted to a trusted origin for GET and POST with our token header; 403 otherwise."""
            self.request_read()
            host = self.headers.get("Host", "")
            method = (self.headers.get("Access-Control-Request-Method") or "").strip().upper()
            origin = trusted_origin(self.headers, trusted)
            if not hosts.allows(host):
                self._refuse(f"Host {host[:100]!r} is not this server")
            elif origin is None:
                self._refuse(f"no CORS for origin {(self.headers.get('Origin') or '(none)')[:100]!r}")
            elif method not in ("GET", "POST"):
                self._refuse(f"no CORS for method {method[:20]!r}")
            else:
                self.send_response(HTTPStatus.NO_CONTENT)
                self.send_header("Access-Control-Allow-Methods", "GET, POST")
                self.send_header("Access-Control-Allow-Headers", f"Content-Type, {TOKEN_HEADER}")
                self.send_header("Access-Control-Max-Age", str(PREFLIGHT_MAX_AGE_S))
                if (self.headers.get("Access-Control-Request-Private-Network") or "").lower() == "true":
                    self.send_header("Access-Control-Allow-Private-Network", "true")  # a public page to the vehicle
                self.send_header("Content-Length", "0")
                self._cors_headers()
                self.end_headers()

    return CorsHandler


def web_port_error(port: int, host: str, err: OSError) -> UsageError:
    """The one line for a page that cannot listen: a port in use (or not ours to take) is a bad ``--web``."""
    if err.errno == errno.EADDRINUSE:
        return UsageError(f"--web {port}: port in use ({host}:{port}); choose another, or 0 for any free port")
    return UsageError(f"--web {port}: cannot listen on {host}:{port} ({err.strerror or err})")


def check_web_port(port: int, host: str = "127.0.0.1") -> None:
    """Before anything starts: the page's port can be had (the same bind options as the server's, so a port held
    only in TIME_WAIT passes); port 0 always can."""
    if not 0 <= port <= 65535:
        raise UsageError(f"--web {port}: not a port (0-65535; 0 picks a free one)")
    if port == 0:
        return
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except OSError as err:
        raise web_port_error(port, host, err) from None


class WebServer:
    """Serves the live page on ``host:port`` until ``close``; port 0 picks a free one (see ``port``).

    ``actions`` are the page's state-changing requests (POST /api/<name>) and ``full_frame`` fetches a frame over
    the link (GET /full/<n>.jpg); both are guarded by ``token`` (new each run), unless a ``guard`` of the page's host
    decides instead (the BlueOS extension's)."""

    def __init__(self, state: Callable[[], dict], gallery_dir: str | Path, port: int, host: str = "127.0.0.1",
                 actions: dict[str, Action] | None = None, *, full_frame: FullFrame | None = None,
                 allowed_hosts: tuple[str, ...] | list[str] = (), pages: Pages | None = None,
                 guard: Guard | None = None, allowed_origins: tuple[str, ...] | list[str] = ()) -> None:
        """``allowed_hosts``: Host headers to answer besides this machine's own names at its port (``name`` or
        ``name:port``), e.g. a reverse proxy's name in front of the page. ``pages``: routes a host of the page adds;
        ``guard``: who may read and change (default: same origin, and this run's token to change);
        ``allowed_origins``: other web origins (``config.web_origin`` form) whose pages may use the JSON and
        actions, with CORS (none: same origin only)."""
        self.token = secrets.token_urlsafe(18)
        self.host = host
        self._hosts = HostPolicy(host, port, allowed_hosts)
        trusted = frozenset(allowed_origins)
        handler = _make_handler(state, Path(gallery_dir), guard or TokenGuard(self._hosts, self.token, trusted),
                                self._hosts, dict(actions or {}), full_frame, pages, trusted)
        try:
            self._server = BoundedHTTPServer((host, port), handler)
        except OSError as err:
            raise web_port_error(port, host, err) from None
        self.port = self._server.server_address[1]
        self._hosts.port = self.port  # port 0 asked: the one the OS gave
        self._thread = threading.Thread(target=self._server.serve_forever, name="surface-web", daemon=True)

    @property
    def url(self) -> str:
        """The page's address with the token, as the tool prints it (the loopback address for a wildcard bind)."""
        shown = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        shown = f"[{shown}]" if ":" in shown else shown
        return f"http://{shown}:{self.port}/?token={self.token}"

    def start(self) -> None:
        self._thread.start()

    def serving(self) -> int:
        """Requests being served now (at most ``http_bounds.MAX_THREADS``)."""
        return self._server.busy()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
