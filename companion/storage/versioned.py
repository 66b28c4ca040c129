"""Versioned settings and store files: refuse a newer one untouched, migrate an older one step by step.

The model is BlueOS's versioned settings (commonwealth ``settings/bases/pydantic_base.py``): every file carries
an integer ``version``; reading a file of an older version runs the migrations from that version up to the
current one, one step at a time (``migrations[n]`` turns version n into n + 1). A file written by a newer
version is never read as if it were ours, nor overwritten later with defaults: the start stops with an error that
names the file and both versions, and the file stays byte for byte as it was.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Any

from companion.errors import MerlionError

Migration = Callable[[dict[str, Any]], dict[str, Any]]


class NewerFileError(MerlionError):
    """A file written by a newer version of merlion than this one."""

    exit_code = 2


def upgrade(path: str | os.PathLike[str], data: Any, *, current: int, migrations: Mapping[int, Migration],
            app_version: str = "") -> dict[str, Any]:
    """``data`` (a parsed file) brought to version ``current``; raises NewerFileError or ValueError (damaged)."""
    if not isinstance(data, dict):
        raise ValueError("not a JSON object")
    version = data.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise ValueError(f"version {version!r} is not a positive whole number")
    if version > current:
        by = f" by merlion {data['written_by']}" if isinstance(data.get("written_by"), str) else ""
        mine = f"merlion {app_version}" if app_version else "this merlion"
        raise NewerFileError(f"{path}: written{by} in format version {version}, but {mine} reads format "
                             f"version {current} at most; left untouched (upgrade merlion, or move the file away)")
    while version < current:
        step = migrations.get(version)
        if step is None:
            raise ValueError(f"no migration from version {version}")
        data = step(dict(data))
        version += 1
        data["version"] = version
    return data
