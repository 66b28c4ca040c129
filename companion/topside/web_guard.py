"""Who may read the live page's state and who may change anything: the Host and Origin checks of ``web``.

A page on another web origin must not read the state (summary, depths, positions, marks) by including
``/state.js`` as a script or fetching ``/api/state``, and a DNS-rebinding name must not reach the server at all:

- every request must carry a Host the server answers to: ``127.0.0.1``, ``localhost`` or ``[::1]`` at the
  server's port, the address it was bound to at that port, any IP address at that port when it listens on every
  interface (a rebinding page can only send names), or without a port (a reverse proxy on port 80 passing
  ``Host $host``, as BlueOS's does: the vehicle's address may be one it got after the server started), or an
  entry of ``allowed_hosts`` (``name`` for any port or ``name:port``), for a reverse proxy in front of the page;
- everything but the page itself (``/``, ``index.html``, ``app.js``: no state in them) is served only to same-origin
  requests: an ``Origin`` or ``Referer`` naming another host, or a ``Sec-Fetch-Site`` other than ``same-origin``
  or ``none`` (what a browser sends for a script or image included by another site), is refused (behind a
  reverse proxy that rewrites Host, its ``X-Forwarded-Host`` counts as the page's own when it is allowed);
- the state as a script (``/state.js``) also needs the request to name its page (``Origin``, ``Referer`` or
  ``Sec-Fetch-Site``): over plain HTTP to a name that is not localhost, a stranger's
  ``<script referrerpolicy="no-referrer">`` sends none of them (browsers send ``Sec-Fetch-*`` only to HTTPS and
  localhost), and a script, unlike JSON, runs in the page that includes it (``unnamed_include``);
- a change (POST) also needs the per-run token;
- an operator may trust other origins by name (``trusted``, off by default: the BlueOS extension's
  ``extension.allowed_origins``, e.g. Cockpit served over HTTP from the topside computer): a request whose ``Origin`` is one of them counts as
  same-origin, and ``web`` answers it and its CORS preflight with CORS headers naming that origin alone.
"""

from __future__ import annotations

import hmac
import ipaddress
from collections.abc import Mapping
from typing import Protocol
from urllib.parse import parse_qs, urlsplit

from companion.config import web_origin

TOKEN_HEADER = "X-Merlion-Token"
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
WILDCARDS = frozenset({"", "0.0.0.0", "::"})


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


class HostPolicy:
    """The Host headers a server bound to ``bind_host:port`` answers to."""

    def __init__(self, bind_host: str, port: int, allowed_hosts: tuple[str, ...] | list[str] = ()) -> None:
        self.bind_host = bind_host.strip("[]").lower()
        self.port = port
        self.extra = frozenset(h.strip().lower() for h in allowed_hosts if h.strip())

    def allows_extra(self, host_header: str) -> bool:
        """Whether ``host_header`` is one of the configured further hosts (``name`` or ``name:port``)."""
        header = host_header.strip().lower()
        try:
            name = urlsplit(f"//{header}").hostname or ""
        except ValueError:
            return False
        return header in self.extra or name in self.extra

    def allows(self, host_header: str | None) -> bool:
        header = (host_header or "").strip().lower()
        if not header:
            return False
        if header in self.extra:
            return True
        try:
            parts = urlsplit(f"//{header}")
            host, port = parts.hostname or "", parts.port
        except ValueError:  # a port that is not a number
            return False
        if host in self.extra:
            return True
        if port is None and self.bind_host in WILDCARDS and _is_ip(host):
            return True  # a proxy's Host $host: an address (a browser sends a port to any port but 80)
        if (port or 80) != self.port:
            return False
        if host in LOOPBACK_NAMES or (host == self.bind_host and self.bind_host not in WILDCARDS):
            return True
        return self.bind_host in WILDCARDS and _is_ip(host)


def trusted_origin(headers, trusted: frozenset[str]) -> str | None:
    """The request's ``Origin`` when it is one the operator trusts (as the browser sent it), else None."""
    origin = headers.get("Origin")
    if not trusted or origin is None:
        return None
    try:
        return origin if web_origin(origin) in trusted else None
    except ValueError:  # "null", or not an origin at all
        return None


PAGE_HEADERS = ("Origin", "Referer", "Sec-Fetch-Site")
"""What a browser's request may say about the page it comes from."""


def unnamed_include(headers: Mapping[str, str]) -> str | None:
    """Why a request for something a page includes (the state as a script, a full frame as an image) is refused
    when it names no page at all; None when it names one (whether that page may have it is the guard's question).

    Naming none is no proof of coming from our page: over plain HTTP to the vehicle's name a stranger's
    ``<script referrerpolicy="no-referrer" src=".../state.js">`` carries no ``Origin`` (a classic script), no
    ``Referer`` and no ``Sec-Fetch-Site`` (sent only to HTTPS and localhost), and the script then runs in the
    stranger's page with the state in it. Our pages send no referrer policy, so their requests carry a ``Referer``."""
    if any(headers.get(name) is not None for name in PAGE_HEADERS):
        return None
    return "a request for the state as a script or a full frame must name its page (Referer)"


def cross_origin(headers, hosts: HostPolicy | None = None, trusted: frozenset[str] = frozenset()) -> str | None:
    """Why a request comes from another web origin than the page's own (None: same origin, or no browser).

    The page's own origin is its Host, or, behind a reverse proxy that rewrites Host, the ``X-Forwarded-Host``
    it adds when that is one of ``hosts``' allowed names (a page cannot add that header to a cross-origin request
    without a CORS preflight, which this server grants only to ``trusted`` origins). A request from a trusted origin
    is let through (its Sec-Fetch-Site and Referer name that origin's page)."""
    if trusted_origin(headers, trusted) is not None:
        return None
    own = {(headers.get("Host") or "").lower()}
    forwarded = (headers.get("X-Forwarded-Host") or "").split(",")[0].strip().lower()
    if forwarded and hosts is not None and hosts.allows_extra(forwarded):
        own.add(forwarded)
    origin = headers.get("Origin")
    if origin is not None and urlsplit(origin).netloc.lower() not in own:
        return f"cross-origin request from {origin[:100]!r}"
    if headers.get("Sec-Fetch-Site") not in (None, "same-origin", "none"):
        return "cross-site request"
    referer = headers.get("Referer")
    if referer is not None and urlsplit(referer).netloc.lower() not in own:
        return "request from another page's origin"
    return None


def refusal(headers, path: str, token: str, hosts: HostPolicy, trusted: frozenset[str] = frozenset()) -> str | None:
    """Why a state-changing request must be refused (None: it may go ahead)."""
    host = headers.get("Host", "")
    if not hosts.allows(host):
        return f"Host {host[:100]!r} is not this server"
    why = cross_origin(headers, hosts, trusted)
    if why is not None:
        return why
    given = parse_qs(urlsplit(path).query).get("token", [""])[0] or headers.get(TOKEN_HEADER, "")
    if not hmac.compare_digest(given.encode(), token.encode()):
        return "missing or wrong token"
    return None


class Guard(Protocol):
    """Who may read the state and who may change anything, once the Host is known to be ours (``web`` asks it).

    ``TokenGuard`` is the surface tool's; the BlueOS extension has its own (``companion/extension/vehicle_guard``):
    behind BlueOS's proxy every answer carries ``Access-Control-Allow-Origin: *``, so no secret may travel in one."""

    def read_refusal(self, headers: Mapping[str, str]) -> str | None:
        """Why a GET of the state (JSON, thumbnails, logs) must be refused; None: it may go ahead."""

    def change_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        """Why a POST (an action) must be refused."""

    def fetch_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        """Why a full-frame fetch (it spends link bandwidth) must be refused."""


class TokenGuard:
    """Same origin (or a trusted one) to read; the per-run token as well to change anything or fetch a frame."""

    def __init__(self, hosts: HostPolicy, token: str, trusted: frozenset[str] = frozenset()) -> None:
        self.hosts = hosts
        self.token = token
        self.trusted = trusted

    def read_refusal(self, headers: Mapping[str, str]) -> str | None:
        return cross_origin(headers, self.hosts, self.trusted)

    def change_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        return refusal(headers, path, self.token, self.hosts, self.trusted)

    def fetch_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        return refusal(headers, path, self.token, self.hosts, self.trusted)
