"""CLIP's query embeddings, for both runtimes: from memory, else the disk cache, else a torch child process.

The text tower (~254 MB for ViT-B-32 fp32, ~150 MB of it touched to encode a few queries) is never loaded in the
companion's process: a query not yet in the cache is encoded by ``clip_child`` in fp32 on the CPU (the reference
numerics, whatever the image tower's precision or device), written to the cache, and read back. The caller waits
(a few seconds, mostly the child's ``import torch``): at start-up, or on the request worker of a live query change,
never on a receive loop. Torch-free, so the ONNX Runtime encoder can use it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

import numpy as np

from companion.errors import MerlionError
from companion.vision.encoders.clip_cache import ClipCache
from companion.vision.encoders.clip_child_runner import run_clip_child
from companion.vision.encoders.weights import ResolvedWeights

log = logging.getLogger(__name__)


def resolved_request(weights: ResolvedWeights) -> dict:
    """The part of a child request that names already-resolved weights (no tag lookup in the child)."""
    return {"resolved": {"path": str(weights.path), "source": weights.source, "preprocess": weights.preprocess}}


class TextEmbeddings:
    """Query text -> L2-normalised fp32 embedding of one (weights, architecture) pair."""

    def __init__(self, cache: ClipCache, weights: ResolvedWeights) -> None:
        self._cache = cache
        self._weights = weights
        self._memory: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()  # a query change (request worker) may race the start-up's encode
        self.child_peak_mb = 0.0
        """The highest peak RSS of the child processes this ran (0: none was needed)."""
        self.children = 0
        """How many child processes this ran (one per call that found texts in neither memory nor the cache)."""

    def get(self, texts: Sequence[str]) -> dict[str, np.ndarray]:
        """Every text's embedding; the ones in neither memory nor the cache are encoded in one child process."""
        with self._lock:
            missing = [t for t in dict.fromkeys(texts) if t not in self._memory]
            if missing:
                self._memory.update(self._cache.texts(missing))
                missing = [t for t in missing if t not in self._memory]
            if missing:
                answer = run_clip_child({"model": self._cache.model, "cache_dir": str(self._cache.root),
                                         "texts": missing, **resolved_request(self._weights)},
                                        f"encode {len(missing)} queries")
                self.child_peak_mb = max(self.child_peak_mb, float(answer["peak_rss_mb"]))
                self.children += 1
                for text, row in (answer.get("embeddings") or {}).items():
                    self._memory[text] = np.asarray(row, dtype=np.float32)
                self._memory.update(self._cache.texts([t for t in missing if t not in self._memory]))
                lost = [t for t in missing if t not in self._memory]
                if lost:
                    raise MerlionError(f"CLIP {self._cache.model}: the child process left no embedding for "
                                       f"{lost[0]!r} in {self._cache.text_dir}")
            return {t: self._memory[t] for t in texts}
