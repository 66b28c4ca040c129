"""The campaign's memory between runs: which dives are finished, and with which inputs and settings.

A dive's key hashes what its output depends on: the source (path, size, and the first and last MiB of each
file, which is cheap and catches a replaced video without reading hours of footage), the matched log (path,
size, its last MiB) and start time, and every setting that changes a summary or its tags. A rerun skips a dive
whose key is recorded as finished; a changed setting gives a new key and the dive is done again. Only the driver
writes the manifest (one owner), atomically after every dive, so a killed run loses at most the dives in flight.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.atomic_write import atomic_write
from companion.config import Config
from companion.errors import MerlionError

VERSION = 1
NAME = "manifest.json"
_SAMPLE = 1 << 20
SETTING_SECTIONS = ("encoder", "queries", "sampler", "enhance", "telemetry")


def _file_digest(h: Any, path: Path, head: bool = True) -> None:
    size = path.stat().st_size
    h.update(f"{path}|{size}|".encode())
    with path.open("rb") as f:
        if head:
            h.update(f.read(_SAMPLE))
        if size > _SAMPLE:
            f.seek(max(0, size - _SAMPLE))
            h.update(f.read(_SAMPLE))


def settings_digest(cfg: Config) -> dict:
    """The settings a summary depends on (the source URI excluded: it is the input, hashed on its own)."""
    out = cfg.model_dump(mode="json", include=set(SETTING_SECTIONS))
    out["fps"] = cfg.source.fps
    return out


def dive_key(source: Path, tlog: Path | None, start_time: float, cfg: Config) -> str:
    h = hashlib.sha256()
    for part in sorted(source.iterdir()) if source.is_dir() else [source]:
        if part.is_file():
            _file_digest(h, part)
    if tlog is not None:
        _file_digest(h, tlog, head=False)
        h.update(f"start={start_time:.3f}".encode())
    h.update(json.dumps(settings_digest(cfg), sort_keys=True).encode())
    return h.hexdigest()


@dataclass
class Manifest:
    path: Path
    finished: dict[str, dict] = field(default_factory=dict)
    failed: dict[str, dict] = field(default_factory=dict)

    @classmethod
    def load(cls, out_dir: Path) -> Manifest:
        path = out_dir / NAME
        if not path.exists():
            return cls(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise MerlionError(f"{path}: unreadable manifest ({err}); move it away to start the campaign again") \
                from None
        if not isinstance(doc, dict) or doc.get("version") != VERSION:
            raise MerlionError(f"{path}: manifest version {doc.get('version') if isinstance(doc, dict) else '?'} "
                               f"is not {VERSION}")
        return cls(path, dict(doc.get("finished", {})), dict(doc.get("failed", {})))

    def is_done(self, name: str, key: str) -> bool:
        entry = self.finished.get(name)
        return entry is not None and entry.get("key") == key and (self.path.parent / name / "summary.json").exists()

    def mark_finished(self, name: str, key: str, info: dict) -> None:
        self.finished[name] = {"key": key, **info}
        self.failed.pop(name, None)
        self.save()

    def mark_failed(self, name: str, key: str, error: str) -> None:
        self.failed[name] = {"key": key, "error": error}
        self.finished.pop(name, None)
        self.save()

    def save(self) -> None:
        doc = {"version": VERSION, "finished": self.finished, "failed": self.failed}
        atomic_write(self.path, json.dumps(doc, indent=2, sort_keys=True) + "\n")
