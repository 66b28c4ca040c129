"""The extension's additions to the surface page's web server: what BlueOS and Cockpit read, the compact widget,
and the entry pages that hand a same-origin reader the page's token.

BlueOS's helper wants ``/`` to answer 200 with a ``<title>``; the page needs the run's token in its URL to send
marks. Asked without a token, ``/`` and ``/widget`` answer a tiny titled page that moves on to ``?token=...``
(relative, so it works under /extensionv2/merlion/): only a page of the same origin can read it, a page on another
site cannot (no CORS), and the web server still checks Host, Origin and Sec-Fetch-Site (``web_guard``).
"""

from __future__ import annotations

import html
import json
from collections.abc import Callable
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from companion.extension.metadata import TITLE, cockpit_extras, register_service
from companion.topside.web import Pages

HTML = "text/html; charset=utf-8"
JSON = "application/json"
Route = Callable[[str], tuple[bytes, str]]
OPEN = frozenset({"/", "/index.html", "/widget", "/widget.js", "/icon.svg"})
"""Pages and assets without state, served like the page itself; the JSON routes go to the same origin only."""


def _static(package: str, name: str) -> bytes:
    return resources.files(package).joinpath("static", name).read_bytes()


def _with_token(page: Callable[[], bytes], token: str, here: str) -> Route:
    """``page`` when the URL carries a token; otherwise the titled stub that reloads ``here`` with it."""

    def route(path: str) -> tuple[bytes, str]:
        if parse_qs(urlsplit(path).query).get("token"):
            return page(), HTML
        target = html.escape(f"{here}?token={token}", quote=True)
        return (f"<!doctype html><meta charset='utf-8'><title>{html.escape(TITLE)}</title>"
                f"<meta http-equiv='refresh' content='0; url={target}'>"
                f"<p><a href='{target}'>{html.escape(TITLE)}</a></p>\n").encode(), HTML

    return route


def extension_pages(*, version: str, token: str, topics: list[str], status: Callable[[], dict]) -> Pages:
    """The routes the extension adds; ``status`` answers ``/api/extension`` (is the companion running, which
    topics can be switched to)."""
    def document(make: Callable[[], dict]) -> Route:
        return lambda _path: (json.dumps(make()).encode(), JSON)

    def asset(name: str, ctype: str) -> Route:
        return lambda _path: (_static("companion.extension", name), ctype)

    return Pages(routes={
        "/": _with_token(lambda: _static("companion.topside", "index.html"), token, "./"),
        "/index.html": _with_token(lambda: _static("companion.topside", "index.html"), token, "index.html"),
        "/widget": _with_token(lambda: _static("companion.extension", "widget.html"), token, "widget"),
        "/widget.js": asset("widget.js", "text/javascript; charset=utf-8"),
        "/icon.svg": asset("icon.svg", "image/svg+xml"),
        "/register_service": document(lambda: register_service(version)),
        "/cockpit_extras.json": document(lambda: cockpit_extras(version, token, topics)),
        "/api/extension": document(status),
    }, open_paths=OPEN)
