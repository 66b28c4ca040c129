"""Who may read the extension's state and use its actions, behind BlueOS's proxy.

BlueOS's nginx (bluerobotics/BlueOS ``core/tools/nginx/nginx.conf``) adds ``Access-Control-Allow-Origin *`` to
every successful answer of its port 80, the extension's included: any web site can read what a GET returns there.
So no secret may travel in a GET (the surface tool's per-run token did, in ``/`` and ``cockpit_extras.json``), and
Cockpit keeps an applied action with its headers for good, so a per-run secret would break it after a restart.
The check needs no secret: browsers name the page a request comes from (``Origin``, ``Referer``,
``Sec-Fetch-Site``) and a page cannot forge them.

- A vehicle page is one served by the vehicle itself: an origin whose host is one of the vehicle's names or IP
  addresses, at any port (BlueOS on port 80, Cockpit's extension on its own port, or BlueOS reached on another
  port; BlueOS's proxy passes ``Host $host``, without the port). Every BlueOS service answers those pages without
  any check, so trusting them gives nothing away; a stranger's page, or a DNS-rebinding name, is not one.
- Read (state, thumbnails, logs, a full frame): refused when the request names another page (``Origin`` or
  ``Referer`` not a vehicle page or a trusted origin) or, naming none, comes from another site
  (``Sec-Fetch-Site: cross-site``, a ``<script>`` or ``<img>`` of a stranger's page). Over plain HTTP to a
  vehicle name a browser sends no ``Sec-Fetch-Site``, and a page can send no ``Referer``
  (``referrerpolicy="no-referrer"``): what runs or costs in the including page (the state as a script, a full
  frame) must name its page (``web_guard.unnamed_include``); JSON and images a stranger cannot read without CORS,
  and a CORS request always carries ``Origin``.
- Change (POST): only with an ``Origin`` of a vehicle page or a trusted origin. Browsers send ``Origin`` with every
  POST, so a stranger's form or fetch (CSRF) is refused; a client that is not a browser can send any header, but
  on BlueOS's network it can already use BlueOS's own terminal.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterable, Mapping
from urllib.parse import urlsplit

import psutil

from companion.topside.web_guard import trusted_origin, unnamed_include

BEACON_NAMES = ("blueos", "blueos-ethernet", "companion", "blueos-wifi", "blueos-hotspot")
"""The names BlueOS's beacon gives the vehicle on its interfaces (bluerobotics/BlueOS
``core/services/beacon/default-settings.json``: eth0 ``blueos``, ``blueos-ethernet``, ``companion``; wlan0
``blueos-wifi``; uap0 ``blueos-hotspot``), reached as ``NAME.local`` over mDNS."""
OTHER_NAMES = ("blueos-avahi.local",)
"""The name BlueOS's avahi service announces."""


def vehicle_names(extra: Iterable[str] = ()) -> tuple[str, ...]:
    """Every host name the vehicle is reached by: the beacon's names with and without ``.local``, and ``extra``
    (``--allow-host``: a vehicle renamed in BlueOS)."""
    names = [n for name in BEACON_NAMES for n in (f"{name}.local", name)]
    return tuple(dict.fromkeys(n.strip().lower() for n in (*names, *OTHER_NAMES, *extra) if n.strip()))


def own_addresses() -> list[str]:
    """This machine's IP addresses now (with host networking, the vehicle's): asked per request, since an interface
    may get its address after the extension started (a Wi-Fi lease, BlueOS's hotspot) or change it."""
    return sorted({a.address.split("%")[0].lower() for addrs in psutil.net_if_addrs().values() for a in addrs
                   if a.family in (socket.AF_INET, socket.AF_INET6)})


def _host(url: str) -> str | None:
    try:
        parts = urlsplit(url)
        return (parts.hostname or "").lower() if parts.scheme in ("http", "https") else None
    except ValueError:
        return None


class VehicleGuard:
    """The checks of the module's docstring for the vehicle's ``names``, its IP addresses as ``addresses`` gives
    them at the time of each request, and ``trusted`` origins."""

    def __init__(self, names: Iterable[str], trusted: frozenset[str] = frozenset(),
                 addresses: Callable[[], Iterable[str]] = own_addresses) -> None:
        self.names = frozenset(h.strip("[]").lower() for h in names if h)
        self.trusted = trusted
        self.addresses = addresses

    def hosts(self) -> frozenset[str]:
        """The vehicle's names and its addresses now."""
        return self.names | {a.strip("[]").lower() for a in self.addresses()}

    def vehicle_page(self, url: str) -> bool:
        """Whether ``url`` (an Origin or a Referer) is a page the vehicle serves."""
        host = _host(url)
        return host is not None and (host in self.names or host in self.hosts())

    def _named(self, headers: Mapping[str, str], name: str) -> bool | None:
        value = headers.get(name)
        if value is None:
            return None
        return self.vehicle_page(value)

    def read_refusal(self, headers: Mapping[str, str]) -> str | None:
        if trusted_origin(headers, self.trusted) is not None:
            return None
        origin, referer = self._named(headers, "Origin"), self._named(headers, "Referer")
        if origin is False:
            return f"request from another site's page {headers.get('Origin', '')[:100]!r}"
        if referer is False:
            return "request from another site's page"
        if origin is None and referer is None and headers.get("Sec-Fetch-Site") == "cross-site":
            return "cross-site request"
        return None

    def change_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        if trusted_origin(headers, self.trusted) is not None or self._named(headers, "Origin"):
            return None
        origin = headers.get("Origin")
        if origin is None:
            return "a change needs the Origin of a page the vehicle serves"
        return f"cross-origin request from {origin[:100]!r}"

    def fetch_refusal(self, headers: Mapping[str, str], path: str) -> str | None:
        """A full frame is an image the page shows: no ``Origin`` comes with it, so it is read like the state, and
        it must name its page: each one spends the link's bandwidth, and a stranger's
        ``<img referrerpolicy="no-referrer">`` would otherwise name none and be served (``unnamed_include``)."""
        return self.read_refusal(headers) or unnamed_include(headers)

    def frame_ancestors(self) -> str:
        """The ``Content-Security-Policy`` that lets only vehicle pages (BlueOS, Cockpit) and trusted origins frame
        the page and the widget: a stranger's invisible frame cannot get a pilot's click. IPv6 literals have no
        form there; names and IPv4 addresses do."""
        sources = ["'self'"]
        for host in sorted(self.hosts()):
            if ":" not in host:
                sources += [f"http://{host}:*", f"https://{host}:*"]
        sources += sorted(self.trusted)
        return "frame-ancestors " + " ".join(sources)
