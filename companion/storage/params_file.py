"""The operator's live parameter values on disk (``params.json`` in the store), saved crash-safely.

The MAVLink side (``vehicle.camera.params.ParamServer``) holds and serves the values; this file is where the app
keeps them between runs, written with ``atomic_write`` so a power cut leaves the old or the new file.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from companion.storage.atomic_write import atomic_write

log = logging.getLogger(__name__)

FILE_VERSION = 1


class ParamsFile:
    """``load()`` the saved values (a damaged file is logged and ignored); ``save(values)`` replaces them."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def load(self) -> dict[str, float]:
        if not self.path.exists():
            return {}
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            if data.get("version") != FILE_VERSION:
                raise ValueError(f"version {data.get('version')!r}, expected {FILE_VERSION}")
            saved = data["params"]
            if not isinstance(saved, dict):
                raise TypeError("params is not an object")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            log.warning("%s: ignoring saved parameters (%s)", self.path, err)
            return {}
        return saved

    def save(self, values: dict[str, float]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(self.path, json.dumps({"version": FILE_VERSION, "params": values}, indent=1) + "\n")
