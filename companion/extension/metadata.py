"""What BlueOS and Cockpit read from the extension: ``/register_service`` and ``/cockpit_extras.json``.

BlueOS's helper scans the vehicle's TCP ports; a service whose ``/`` has a ``<title>`` and whose
``/register_service`` answers JSON gets a sidebar entry, served under ``/extensionv2/<name>/`` when it works in
relative paths (every URL of our page is relative). Cockpit reads the file named by ``extras.cockpit``: its iframe
widgets (both spellings of the URL key: its docs say ``iframeUrl``, older code reads ``iframe_url``), its actions
(HTTP requests to ``{{ vehicle-address }}``, which Cockpit fills in) and joystick suggestions.
"""

from __future__ import annotations

import json
from typing import Any

NAME = "merlion"
"""The extension's name: lower-case letters only, so BlueOS serves it at /extensionv2/merlion/."""
TITLE = "MERLION Companion"
COMPANY = "MERLION"
BASE = f"/extensionv2/{NAME}"
"""Where BlueOS serves the page; Cockpit's HTTP actions go through it (same origin as Cockpit in BlueOS)."""
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
        "route": "/",
        "new_page": False,
        "works_in_relative_paths": True,
        "avoid_iframes": False,
        "extras": {"cockpit": "/cockpit_extras.json"},
    }


def _http_action(ident: str, name: str, path: str, body: str, token: str) -> dict[str, Any]:
    return {"id": f"{NAME}-{ident}", "name": name, "type": "http-request", "version": "1.0.0", "config": {
        "name": name, "url": f"http://{{{{ vehicle-address }}}}{BASE}/api/{path}", "method": "POST",
        "headers": {"Content-Type": "application/json", "X-Merlion-Token": token}, "urlParams": {}, "body": body}}


def cockpit_extras(version: str, token: str, topics: list[str]) -> dict[str, Any]:
    """The widget, the actions (start, stop, mark the newest frame, one per preset topic) for Cockpit.

    ``token`` is the page's: Cockpit reads this file from the vehicle as the page does, and a page on another
    site can read neither (no CORS), so it lets Cockpit's actions through the same checks as the page's buttons.
    """
    widget_url = "/widget"  # under the extension's path in BlueOS (useExtensionPathAsBaseUrl), or on our own port
    actions = [
        _http_action("start", "MERLION: start the companion", "companion", '{"run":true}', token),
        _http_action("stop", "MERLION: stop the companion", "companion", '{"run":false}', token),
        _http_action("like-newest", "MERLION: more like the newest frame", "mark-newest", '{"kind":"like"}', token),
        _http_action("unlike-newest", "MERLION: not the newest frame", "mark-newest", '{"kind":"unlike"}', token),
    ]
    actions += [_http_action(f"topic-{t}", f"MERLION: follow {t}", "topic", json.dumps({"topic": t}), token)
                for t in topics]
    return {
        "targetSystem": "Cockpit",
        "targetCockpitApiVersion": COCKPIT_API,
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
