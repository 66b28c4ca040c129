"""Facts about BlueOS that the extension must fit, each read from BlueOS's own source (bluerobotics/BlueOS; the
commits are those of the copies read), kept here as data so the tests derive what they check from them.

- ``core/services/helper/main.py`` (2030977): ``detect_service`` GETs ``/`` (200 and a ``<title>``) and
  ``/register_service`` of every listening port, sets ``sanitized_name = re.sub(r"[^a-z0-9]", "", name.lower())``,
  and ``setup_nginx_route`` writes the location block below to ``extensions/<sanitized_name>.conf``;
  ``BLUEOS_SYSTEM_SERVICES_PORTS`` and ``SKIP_PORTS`` are the ports of its own services and those it never scans.
- ``core/tools/nginx/nginx.conf`` (b1b6909): the port-80 server adds ``Access-Control-Allow-Origin *`` at server
  level, includes ``/home/pi/tools/nginx/extensions/*.conf``, proxies its own services' ports, and serves its
  frontend at ``/`` and for every path matching ``~* \\.html$``.
- ``core/frontend/src/App.vue`` (9816bcd): the sidebar links ``route ?? address``; ``address`` is
  ``/extensionv2/${sanitized_name}/`` for a service that ``works_in_relative_paths``.
- ``core/services/beacon/default-settings.json`` (749689a): the vehicle's names per interface.
"""

from __future__ import annotations

SANITIZE_PATTERN = r"[^a-z0-9]"
"""The helper's rule, applied to the lower-cased service name."""

LOCATION_TEMPLATE = """
        location /extensionv2/{name}/ {{
        proxy_pass http://127.0.0.1:{port}/;
        proxy_set_header Host $host;
        proxy_set_header X-Real-IP $remote_addr;
        proxy_set_header X-Forwarded-For $proxy_add_x_forwarded_for;
        proxy_set_header X-Forwarded-Proto $scheme;
        }}
        """
"""The helper's ``setup_nginx_route`` text, as it writes it (format fields: name, port)."""

SERVER_HEADERS = ("add_header Access-Control-Allow-Origin *;",)
"""Server-level directives of nginx.conf's port-80 server that every extension route inherits."""

FRONTEND_LOCATIONS = r"""
        location / {{
            root {frontend};
            try_files $uri $uri/ /index.html;
        }}
        location ~* \.html$ {{
            root {frontend};
            try_files $uri $uri/ /index.html;
            expires -1;
            add_header Cache-Control no-store;
        }}
        """
"""nginx.conf's port-80 locations for BlueOS's own frontend (format field: frontend), beside the extensions'. The
regular expression beats every prefix location, ``/extensionv2/<name>/`` included: any path of the extension
ending in ``.html`` is BlueOS's frontend, never the extension's page."""

SIDEBAR_ADDRESS = "/extensionv2/{name}/"
"""App.vue's ``createExtensionAddress`` for ``works_in_relative_paths``; the link is ``route ?? address``."""

SYSTEM_SERVICE_PORTS = frozenset({81, 2748, 6020, 6030, 6040, 7777, 8000, 8081, 8088, 9000, 9002, 9090, 9100, 9101,
                                  9110, 9111, 9120, 9134, 9150, 27353})
"""The helper's ``BLUEOS_SYSTEM_SERVICES_PORTS`` (9110: Ping)."""
SKIP_PORTS = frozenset({22, 80, 5201, 6021, 7000, 8554, 5777, 5555, 2770})
"""The helper's ``SKIP_PORTS``."""
NGINX_PORTS = frozenset({80, 2770, 8000, 9101, 9111, 27353, 9090, 9100, 81, 9134, 2748, 6040, 6021, 6020, 9120, 6030,
                         8088, 8081, 9000, 9110})
"""Ports nginx.conf listens on or proxies to."""

BEACON_NAMES = {"eth0": ("blueos", "blueos-ethernet", "companion"), "wlan0": ("blueos-wifi",),
                "uap0": ("blueos-hotspot",)}
"""default-settings.json's ``domain_names`` per interface, announced as ``NAME.local``."""
