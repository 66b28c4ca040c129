"""The extension's additions to the surface page's web server: what BlueOS and Cockpit read and the compact widget.

No page carries a secret (behind BlueOS's proxy any site can read what a GET returns: ``vehicle_guard``), so ``/``
is the surface page itself: BlueOS's helper wants it to answer 200 with a ``<title>``. Every URL of the pages is
relative, so they work under /extensionv2/<name>/ and on the extension's own port alike.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib import resources

from companion.extension.metadata import cockpit_extras, register_service
from companion.topside.web import Pages

HTML = "text/html; charset=utf-8"
JSON = "application/json"
Route = Callable[[str], tuple[bytes, str]]
OPEN = frozenset({"/", "/index.html", "/widget", "/widget.js", "/icon.svg", "/register_service",
                  "/cockpit_extras.json"})
"""Served whatever the origin: pages and assets without state, and what BlueOS's helper and Cockpit (from its own
origin) read; the state and the actions follow ``vehicle_guard``."""


def _static(package: str, name: str) -> bytes:
    return resources.files(package).joinpath("static", name).read_bytes()


def extension_pages(*, version: str, topics: list[str], status: Callable[[], dict],
                    frame_ancestors: Callable[[], str]) -> Pages:
    """The routes the extension adds; ``status`` answers ``/api/extension`` (is the companion running, which
    topics can be switched to); ``frame_ancestors`` gives the CSP that says who may frame the pages (asked per answer: the vehicle's addresses
    change while it runs)."""
    def document(make: Callable[[], dict]) -> Route:
        return lambda _path: (json.dumps(make()).encode(), JSON)

    def asset(package: str, name: str, ctype: str) -> Route:
        return lambda _path: (_static(package, name), ctype)

    return Pages(routes={
        "/": asset("companion.topside", "index.html", HTML),
        "/index.html": asset("companion.topside", "index.html", HTML),
        "/widget": asset("companion.extension", "widget.html", HTML),
        "/widget.js": asset("companion.extension", "widget.js", "text/javascript; charset=utf-8"),
        "/icon.svg": asset("companion.extension", "icon.svg", "image/svg+xml"),
        "/register_service": document(lambda: register_service(version)),
        "/cockpit_extras.json": document(lambda: cockpit_extras(version, topics)),
        "/api/extension": document(status),
    }, open_paths=OPEN, headers={"Content-Security-Policy": frame_ancestors, "X-Content-Type-Options": "nosniff"})
