"""CLIP with ``runtime: onnx``: the exported image tower run by ONNX Runtime, in a process that never imports torch.

``import torch`` + open_clip cost ~730 MB of RSS here before any weight, which alone would break the 1.2 GB
budget. This encoder needs only onnxruntime, numpy, PIL and the cache (``clip_cache``): the exported tower and
its preprocessing, and the text embedding of every query already asked. What needs torch (resolving a pretrained
tag, the first export, queries not in the cache) runs in a short-lived child process (``clip_child``) that fills
the cache and exits; the child's peak is reported apart (``child_peaks_mb``) since it is transient.

Measured on the 2-core AVX2 build machine: 1.4x (batch 8) to 2.7x (batch 1) the frames/s of torch's fp32 tower
with the same embeddings (cosine 1.000000).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from companion.atomic_write import atomic_write
from companion.config import EncoderConfig
from companion.errors import MerlionError, UsageError
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.clip_cache import ClipCache, cache_root
from companion.vision.encoders.clip_child_runner import run_clip_child
from companion.vision.encoders.clip_pixels import NumpyClipPreprocess
from companion.vision.encoders.clip_scores import positive_share
from companion.vision.encoders.clip_texts import TextEmbeddings, resolved_request
from companion.vision.encoders.cpu_threads import intra_op_threads
from companion.vision.encoders.heap_trim import release_freed_memory
from companion.vision.encoders.weights import ResolvedWeights, resolve_clip_weights
from companion.vision.onnx_runtime import onnxruntime

log = logging.getLogger(__name__)


def _resolution_record(root: Path, model: str, tag: str) -> Path:
    return root / "resolved" / f"{model}-{tag}.json"


def recorded_weights(cfg: EncoderConfig) -> ResolvedWeights | None:
    """The checkpoint a child process found for ``encoder.pretrained`` on an earlier start, if still on disk.

    Looking a tag up needs open_clip (and so torch); the answer is kept so that a later start does not.
    """
    if not cfg.pretrained:
        return None
    record = _resolution_record(cache_root(cfg.cache_dir), cfg.model, cfg.pretrained)
    try:
        found = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    path = Path(found.get("weights", ""))
    if not path.is_file():
        return None
    return ResolvedWeights(path=path, source=found["source"], preprocess=found.get("preprocess") or {})


class OnnxClipEncoder(Encoder):
    """CLIP's image tower in ONNX Runtime (fp32), text embeddings from the cache; no torch in this process."""

    def __init__(self, cfg: EncoderConfig) -> None:
        ort = onnxruntime("encoder.runtime onnx")
        if cfg.precision not in ("auto", "fp32") or cfg.device == "cuda":
            raise UsageError(f"encoder.runtime onnx runs the fp32 export (precision {cfg.precision}, device "
                             f"{cfg.device}): use precision fp32 (GPUs through encoder.providers) or runtime torch")
        providers = list(cfg.providers) or ["CPUExecutionProvider"]
        available = ort.get_available_providers()
        missing = [p for p in providers if p not in available]
        if missing:  # checked before any export: a vehicle without CUDA learns it in one line, at once
            raise UsageError(f"encoder.providers: {missing[0]} is not in this onnxruntime build "
                             f"(available: {', '.join(available)})")
        self.providers = providers
        self.name = f"clip:{cfg.model}"
        self._cfg = cfg
        self._root = cache_root(cfg.cache_dir)
        self._export_peak_mb = 0.0

        self._exported = False
        self._weights = self._resolve()
        self._cache = ClipCache(self._root, self._weights.path, cfg.model, self._weights.preprocess)
        if not self._cache.has_tower():
            self._child({"export": True, **resolved_request(self._weights)}, "export the image tower to ONNX")
        self.cached = not self._exported
        """Whether the exported tower was already in the cache (False: this start exported it in a child)."""
        manifest = self._cache.read_manifest()
        self.preprocess = NumpyClipPreprocess(manifest["preprocess"])
        self._dim = int(manifest["dim"]) or None

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = intra_op_threads()
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # idle ORT workers otherwise spin, taking the two cores from the decode thread
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self._session = ort.InferenceSession(str(self._cache.onnx_path), opts, providers=providers)
        except Exception as err:  # a damaged cache file: say which, so it can be deleted
            reason = " ".join(str(err).split())[:160]
            raise MerlionError(f"encoder.cache_dir: cannot load the exported tower {self._cache.onnx_path} "
                               f"({reason}); delete it to export again") from None
        release_freed_memory()  # the session build's transient buffers
        self._texts = TextEmbeddings(self._cache, self._weights)
        self._batch = cfg.batch
        log.info("CLIP %s image tower from %s (%s) in ONNX Runtime %s, %s export", cfg.model, self._weights.path,
                 self._weights.source, providers, "cached" if self.cached else "new")

    def _resolve(self) -> ResolvedWeights:
        """``encoder.weights`` as is (no torch needed); a tag from the record of an earlier start, or a child."""
        cfg = self._cfg
        if cfg.weights or not cfg.pretrained:  # a file, or nothing to look up: says so in one line, torch-free
            return resolve_clip_weights(cfg.model, cfg.weights, cfg.pretrained)
        found = recorded_weights(cfg)
        if found is not None:
            return found
        answer = self._child({"export": True, "weights": None, "pretrained": cfg.pretrained},
                             f"find the weights of {cfg.pretrained} and export the image tower")
        record = _resolution_record(self._root, cfg.model, cfg.pretrained)
        record.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(record, json.dumps({"weights": answer["weights"], "source": answer["source"],
                                         "preprocess": answer["preprocess"]}))
        return ResolvedWeights(path=Path(answer["weights"]), source=answer["source"],
                               preprocess=answer["preprocess"])

    def _child(self, request: dict, what: str) -> dict:
        answer = run_clip_child({"model": self._cfg.model, "cache_dir": str(self._root), **request}, what)
        self._export_peak_mb = max(self._export_peak_mb, float(answer["peak_rss_mb"]))
        self._exported |= bool(answer.get("exported"))
        return answer

    @property
    def child_peaks_mb(self) -> dict[str, float]:
        """Peak RSS of the torch child processes this encoder ran ("export", "texts"): transient, so reported
        apart from this process's."""
        peaks = {"export": self._export_peak_mb, "texts": self._texts.child_peak_mb}
        return {k: v for k, v in peaks.items() if v}

    @property
    def precision(self) -> str:
        return "fp32"

    @property
    def input_size(self) -> tuple[int, int]:
        h, w = self.preprocess.size
        return (w, h)

    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for start in range(0, len(images), self._batch):
            batch = self.preprocess.batch(images[start:start + self._batch])
            emb = self._session.run(None, {"image": batch})[0]
            out.append(emb / np.linalg.norm(emb, axis=1, keepdims=True))
        if not out:
            return np.zeros((0, self._embed_dim()), dtype=np.float32)
        return np.concatenate(out).astype(np.float32, copy=False)

    def _embed_dim(self) -> int:
        return self._dim or int(self.encode_texts(["x"]).shape[1])

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """From memory, the disk cache, or a torch child process (``clip_texts``)."""
        if not texts:
            return np.zeros((0, self._embed_dim()), dtype=np.float32)
        found = self._texts.get(texts)
        return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return positive_share(image_embeddings, text_embeddings)

    def describe(self) -> dict:
        return {"name": self.name, "model": self._cfg.model, "weights": str(self._weights.path),
                "weights_source": self._weights.source, "precision": self.precision, "runtime": "onnx",
                "providers": self.providers, "device": "cpu" if self.providers == ["CPUExecutionProvider"] else
                self.providers[0], "input_size": list(self.input_size), "export_cached": self.cached}
