"""What CLIP leaves on disk between starts, so a later start needs no torch: the exported image tower, the
preprocessing it was trained with, and the text embeddings of every query already asked.

Everything is keyed by the weights' identity (the file's resolved path, size and mtime; for a model folder, those
of every file in it), the architecture and the torch/open_clip versions (read from the installed packages'
metadata, so this module never imports them): replaced weights or an upgraded exporter give a new key, so nothing
stale is ever read. Files are written whole or not at all (a rename), and the manifest is written last: a start
cut short leaves no tower that looks complete.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
from importlib import metadata
from pathlib import Path

import numpy as np

from companion.atomic_write import atomic_write

log = logging.getLogger(__name__)


def cache_root(cache_dir: str | Path | None) -> Path:
    """``encoder.cache_dir``; unset: the cache directory systemd gives the service (``CacheDirectory=``, in
    ``$CACHE_DIRECTORY``: the service user has no writable home), else ``$XDG_CACHE_HOME/merlion``, else
    ``~/.cache/merlion``."""
    if cache_dir:
        return Path(cache_dir).expanduser()
    given = os.environ.get("CACHE_DIRECTORY", "").split(":")[0]
    if given:
        return Path(given)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return Path(xdg) / "merlion" if xdg else Path.home() / ".cache" / "merlion"


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "-"


def weights_identity(path: Path) -> str:
    """The weights' path, size and mtime (every file's, for an open_clip model folder)."""
    path = path.resolve()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return ";".join(f"{p}|{p.stat().st_size}|{p.stat().st_mtime_ns}" for p in files)


class ClipCache:
    """The cached artefacts of one (weights, architecture) pair under ``root``."""

    def __init__(self, root: Path, weights: Path, model: str, preprocess: dict | None = None) -> None:
        """``preprocess``: a pretrained tag's overrides of the architecture's preprocessing (mean, std, ...): the
        same file reached through a tag that declares others must not get the other's tower manifest."""
        parts = [weights_identity(weights), model, _version("torch"), _version("open_clip_torch")]
        if preprocess:  # absent for a plain file: caches made before this keep their key
            parts.append(json.dumps(preprocess, sort_keys=True))
        key = "|".join(parts)
        digest = hashlib.sha256(key.encode()).hexdigest()[:16]
        self.root = root
        self.model = model
        self.onnx_path = root / "onnx" / f"{model}-{digest}.onnx"
        """The exported image tower (fp32, dynamic batch)."""
        self.manifest_path = root / "onnx" / f"{model}-{digest}.json"
        """Preprocessing and embedding size of the tower beside it; written after it."""
        self.text_dir = root / "text" / f"{model}-{digest}"
        """One ``.npy`` per query text, named by the text's hash."""

    def has_tower(self) -> bool:
        return self.onnx_path.is_file() and self.manifest_path.is_file()

    def read_manifest(self) -> dict:
        return json.loads(self.manifest_path.read_text(encoding="utf-8"))

    def write_tower_manifest(self, manifest: dict) -> None:
        """Called once the tower file is in place: its presence is what makes the tower usable."""
        self.manifest_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(self.manifest_path, json.dumps(manifest, indent=1))

    def _text_file(self, text: str) -> Path:
        return self.text_dir / f"{hashlib.sha256(text.encode('utf-8')).hexdigest()[:32]}.npy"

    def texts(self, texts: list[str]) -> dict[str, np.ndarray]:
        """The cached embeddings among ``texts`` (missing ones are simply absent)."""
        found = {}
        for text in dict.fromkeys(texts):
            path = self._text_file(text)
            if path.is_file():
                try:
                    found[text] = np.load(path, allow_pickle=False).astype(np.float32, copy=False)
                except (OSError, ValueError) as err:  # unreadable: encoded again, and rewritten
                    log.warning("ignoring unreadable cached text embedding %s: %s", path, err)
        return found

    def put_text(self, text: str, embedding: np.ndarray) -> bool:
        """Keep one embedding for later starts; False (logged) when the cache cannot be written: the embedding
        still serves this run, which gets it from the child's answer."""
        try:
            self.text_dir.mkdir(parents=True, exist_ok=True)
            buf = io.BytesIO()
            np.save(buf, np.asarray(embedding, dtype=np.float32), allow_pickle=False)
            atomic_write(self._text_file(text), buf.getvalue())
        except OSError as err:
            log.warning("CLIP query embedding not cached in %s (%s); set encoder.cache_dir to a writable folder",
                        self.text_dir, err.strerror or err)
            return False
        return True
