"""The topics the surface uploaded (``queries.json`` in the store), so a restart keeps following them.

An operator who switched the vehicle to new topics mid-dive expects a reboot to carry on with them, and the
summary frames those topics already hold are saved data: a restart on the configured topics would drop them.
So an accepted upload is saved with the topics the configuration listed at that moment, and at start the
uploaded topics win while the configuration still lists what it listed then. When the configuration changed
since (someone edited it on purpose), it wins and the saved upload is set aside (logged).

Written with ``atomic_write`` and versioned like ``params.json`` and ``marks.json``: a damaged file is logged and
ignored, a file from a newer merlion stops the start and is left untouched.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.atomic_write import atomic_write
from companion.storage.versioned import upgrade

log = logging.getLogger(__name__)

FILE_VERSION = 1


@dataclass(frozen=True)
class SavedQueries:
    """Uploaded topics, and the configured ones they replaced (each a list of {name, positive, negatives})."""

    topics: list[dict[str, Any]]
    configured: list[dict[str, Any]]


def topic_dicts(topics) -> list[dict[str, Any]]:
    """Topics (config entries, specs or wire topics: anything with name/positive/negatives) as plain data."""
    return [{"name": t.name, "positive": t.positive, "negatives": list(t.negatives)} for t in topics]


def _topics(value: object, key: str) -> list[dict[str, Any]]:
    ok = isinstance(value, list) and value and all(
        isinstance(t, dict) and isinstance(t.get("name"), str) and isinstance(t.get("positive"), str)
        and isinstance(t.get("negatives"), list) and all(isinstance(n, str) for n in t["negatives"]) for t in value)
    if not ok:
        raise TypeError(f"{key} is not a list of topics")
    return [{"name": t["name"], "positive": t["positive"], "negatives": list(t["negatives"])} for t in value]


class QueriesFile:
    """``load()`` the saved upload (None when there is none); ``save(...)`` replaces it."""

    def __init__(self, path: str | os.PathLike[str], *, version: str = "",
                 guard: Callable[[], None] | None = None) -> None:
        self.path = Path(path)
        self.version = version
        self.guard = guard or (lambda: None)
        """Asked before a write (``StoreLock.check``): OSError when the store folder is no longer this run's."""

    def load(self) -> SavedQueries | None:
        """The saved upload (None when absent or damaged); raises NewerFileError for a newer version's file."""
        if not self.path.exists():
            return None
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            log.warning("%s: ignoring saved queries (%s)", self.path, err)
            return None
        try:
            data = upgrade(self.path, data, current=FILE_VERSION, migrations={}, app_version=self.version)
            return SavedQueries(_topics(data.get("topics"), "topics"), _topics(data.get("configured"), "configured"))
        except (ValueError, TypeError) as err:
            log.warning("%s: ignoring saved queries (%s)", self.path, err)
            return None

    def save(self, saved: SavedQueries) -> None:
        self.guard()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = {"version": FILE_VERSION, "written_by": self.version or "unknown", "topics": saved.topics,
                "configured": saved.configured}
        atomic_write(self.path, json.dumps(body, indent=1) + "\n")
