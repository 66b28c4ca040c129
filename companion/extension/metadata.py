"""What BlueOS and Cockpit read from the extension: ``/register_service`` and ``/cockpit_extras.json``.

BlueOS's helper (bluerobotics/BlueOS ``core/services/helper/main.py``) scans the vehicle's TCP ports; a service whose
``/`` answers with a ``<title>`` and whose ``/register_service`` answers JSON gets a sidebar entry. It names the
service's nginx route from ``name`` (``re.sub(r"[^a-z0-9]", "", name.lower())``) and writes
``location /extensionv2/<that>/`` proxying to the port; its frontend (``core/frontend/src/App.vue``) links
``route ?? address``, so a ``route`` would replace that path: we send none. Cockpit (``src/libs/blueos.ts``) reads
the file named by ``extras.cockpit`` under the same path and prefixes its widgets' ``iframe_url`` and
``iframe_icon`` with it; its HTTP actions (``src/libs/actions/http-request.ts``) are ``fetch`` calls with the
stored method, headers and body, to ``{{ vehicle-address }}``, which Cockpit fills in.
"""

from __future__ import annotations

import json
import re
from typing import Any

TITLE = "MERLION Companion"
COMPANY = "MERLION"


def blueos_path_name(name: str) -> str:
    """The path BlueOS's helper gives a service called ``name``: lower case, every character but a-z and 0-9 gone."""
    return re.sub(r"[^a-z0-9]", "", name.lower())


NAME = blueos_path_name(TITLE)
"""``merlioncompanion``: BlueOS serves the page at /extensionv2/merlioncompanion/."""
BASE = f"/extensionv2/{NAME}"
"""Where BlueOS serves the page; Cockpit's HTTP actions go through it."""
PORT = 9810
"""The page's port on the vehicle (host networking): none of BlueOS's own services or skipped ports in its helper
(``BLUEOS_SYSTEM_SERVICES_PORTS``, ``SKIP_PORTS``: 81, 2748, 6020, 6030, 6040, 7777, 8000, 8081, 8088, 9000, 9002,
9090, 9100, 9101, 9110 (Ping), 9111, 9120, 9134, 9150, 27353; 22, 80, 2770, 5201, 5555, 5777, 6021, 7000, 8554),
none nginx.conf listens on or proxies to, and outside the 9000-9150 block where BlueOS adds its services."""
COCKPIT_API = "1.0.0"
ICON = "mdi-image-filter-center-focus-weak"
"""A Material Design icon name, as BlueOS's sidebar takes them."""


def register_service(version: str) -> dict[str, Any]:
    """The answer to BlueOS's ``GET /register_service``."""
    return {
        "name": TITLE,
        "description": "Keeps the K most diverse frames that match your words and tags them with depth and pose",
        "icon": ICON,
        "company": COMPANY,
        "version": version,
        "webpage": "",
        "api": "",
        "new_page": False,
        "works_in_relative_paths": True,
        "avoid_iframes": False,
        "extras": {"cockpit": "/cockpit_extras.json"},
    }


def _http_action(ident: str, name: str, path: str, body: str) -> dict[str, Any]:
    """No headers: the body (JSON text) goes as text/plain, so Cockpit on another vehicle origin (its extension's
    port) needs no CORS preflight, which BlueOS's proxy would answer with a second Allow-Origin; no secret either:
    this file is readable by any site behind BlueOS's proxy, and Cockpit keeps an action as it was applied."""
    return {"id": f"{NAME}-{ident}", "name": name, "type": "http-request", "version": "1.0.0", "config": {
        "name": name, "url": f"http://{{{{ vehicle-address }}}}{BASE}/api/{path}", "method": "POST",
        "headers": {}, "urlParams": {}, "body": body}}


def cockpit_extras(version: str, topics: list[str]) -> dict[str, Any]:
    """The widget, the actions (start, stop, mark the newest frame, one per preset topic) for Cockpit."""
    widget_url = "/widget"  # under the extension's path in BlueOS (useExtensionPathAsBaseUrl), or on our own port
    actions = [
        _http_action("start", "MERLION: start the companion", "companion", '{"run":true}'),
        _http_action("stop", "MERLION: stop the companion", "companion", '{"run":false}'),
        _http_action("like-newest", "MERLION: more like the newest frame", "mark-newest", '{"kind":"like"}'),
        _http_action("unlike-newest", "MERLION: not the newest frame", "mark-newest", '{"kind":"unlike"}'),
    ]
    actions += [_http_action(f"topic-{t}", f"MERLION: follow {t}", "topic", json.dumps({"topic": t}))
                for t in topics]
    return {
        "targetSystem": "Cockpit",
        "targetCockpitApiVersion": COCKPIT_API,
        "target_system": "Cockpit",  # the spelling of Cockpit's ExtrasJson type (src/libs/blueos.ts)
        "target_cockpit_api_version": COCKPIT_API,
        "widgets": [{
            "name": "MERLION summary",
            "iframeUrl": widget_url,
            "iframe_url": widget_url,
            "iframeIcon": "/icon.svg",
            "iframe_icon": "/icon.svg",
            "useExtensionPathAsBaseUrl": True,
            "version": version,
        }],
        "actions": actions,
        "joystickSuggestions": [{
            "id": f"{NAME}-marks", "name": "MERLION marks", "version": "1.0.0",
            "description": "Mark the newest summary frame from the joystick",
            "buttonMappingSuggestions": [
                {"id": f"{NAME}-like-button", "actionProtocol": "cockpit-action", "actionName": actions[2]["name"],
                 "actionId": actions[2]["id"], "button": 12, "modifierKey": "shift",
                 "description": "more like the newest frame"},
                {"id": f"{NAME}-unlike-button", "actionProtocol": "cockpit-action", "actionName": actions[3]["name"],
                 "actionId": actions[3]["id"], "button": 13, "modifierKey": "shift",
                 "description": "not the newest frame"},
            ]}],
    }
