"""The surface page as files in the gallery folder: DIR/index.html opens from disk, with no server running.

It is the live page itself (the same index.html and app.js) plus ``state.js``, the state it would have polled,
written as a script (a page opened from ``file://`` may not fetch JSON, but it may load a script). Thumbnails
are the gallery's own files, relative to DIR, so the folder can be copied or zipped and still opens.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from companion.atomic_write import atomic_write

PAGE_FILES = ("index.html", "app.js")


def write_offline_page(root: Path, state: dict) -> Path:
    """Write DIR/index.html, app.js (when they changed) and state.js; returns the path of index.html."""
    static = resources.files("companion.topside").joinpath("static")
    for name in PAGE_FILES:
        body = static.joinpath(name).read_bytes()
        target = root / name
        if not target.is_file() or target.read_bytes() != body:
            atomic_write(target, body)
    script = "window.MERLION_STATE = " + json.dumps(state, default=str) + ";\n"  # NaN is valid JavaScript
    atomic_write(root / "state.js", script.encode())
    return root / "index.html"
