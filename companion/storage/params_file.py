"""The operator's live parameter values on disk (``params.json`` in the store), saved crash-safely.

The MAVLink side (``vehicle.camera.params.ParamServer``) holds and serves the values; this file is where the app
keeps them between runs, written with ``atomic_write`` so a power cut leaves the old or the new file.

Versions (``companion.storage.versioned``): 1 held ``params`` only; 2 adds ``written_by``, the merlion version
that saved it, so that a newer file is refused with a message naming that version. A damaged file is logged and
ignored (the configuration's values stand); a file from a newer merlion stops the start and is left untouched.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.atomic_write import atomic_write
from companion.storage.versioned import upgrade

log = logging.getLogger(__name__)

FILE_VERSION = 2


def _v1_to_v2(data: dict[str, Any]) -> dict[str, Any]:
    data["written_by"] = "unknown (format version 1)"
    return data


MIGRATIONS = {1: _v1_to_v2}


class ParamsFile:
    """``load()`` the saved values; ``save(values)`` replaces them. ``version``: this merlion's, for the file."""

    def __init__(self, path: str | os.PathLike[str], *, version: str = "",
                 guard: Callable[[], None] | None = None) -> None:
        self.path = Path(path)
        self.version = version
        self.guard = guard or (lambda: None)
        """Asked before a write (``StoreLock.check``): OSError when the store folder is no longer this run's."""
        self.failing = False

    def load(self) -> dict[str, float]:
        """The saved values ({} when none or damaged); raises NewerFileError for a newer version's file."""
        if not self.path.exists():
            return {}
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            log.warning("%s: ignoring saved parameters (%s)", self.path, err)
            return {}
        try:
            data = upgrade(self.path, data, current=FILE_VERSION, migrations=MIGRATIONS, app_version=self.version)
            saved = data["params"]
            if not isinstance(saved, dict):
                raise TypeError("params is not an object")
        except (ValueError, KeyError, TypeError) as err:
            log.warning("%s: ignoring saved parameters (%s)", self.path, err)
            return {}
        return saved

    def save(self, values: dict[str, float]) -> bool:
        """Replace the saved values; False when the disk refuses (full, read-only): the values still apply this
        run and the PARAM_SET is still answered, only a restart forgets them. Said once per failure streak."""
        body = {"version": FILE_VERSION, "written_by": self.version or "unknown", "params": values}
        try:
            self.guard()
            self.path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(self.path, json.dumps(body, indent=1) + "\n")
        except OSError as err:
            if not self.failing:
                log.warning("%s: cannot save parameters (%s); they apply until the next restart only", self.path,
                            err.strerror or err)
            self.failing = True
            return False
        self.failing = False
        return True
