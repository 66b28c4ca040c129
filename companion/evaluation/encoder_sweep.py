"""Scores of the packaged encoder's settings on the same frames, for the held-out choice of its defaults.

One encoder pass per (backbone, colour correction) yields every view (whole frame, region windows), so region
handling, vocabulary and per-dive normalisation are compared on the same embeddings. Variant names read
``backbone/colour/views/vocabulary[/dive-norm]``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from companion.config import EncoderConfig
from companion.evaluation.sources import LabelledFrame
from companion.vision.encoders.imagenet import CLASSES, FEATURES, ImageNetEncoder
from companion.vision.encoders.query_words import resolve_query

BONY_FISH = (0, 1, 389, 391, 392, 393, 394, 395, 396, 397)
"""Ray-finned fish only (no sharks, rays, eels): the narrower vocabulary tried against the default."""


def _vocabularies() -> dict[str, np.ndarray]:
    fish = np.zeros(CLASSES, np.float32)
    fish[list(resolve_query("fish").classes)] = 1.0
    bony = np.zeros(CLASSES, np.float32)
    bony[list(BONY_FISH)] = 1.0
    return {"fish": fish, "bony": bony}


def _views(mass: np.ndarray) -> dict[str, np.ndarray]:
    """(N, V) positive mass per view -> score per view rule."""
    return {"whole": mass[:, 0], "max": mass.max(axis=1), "mean": mass.mean(axis=1),
            "max+whole": 0.5 * (mass.max(axis=1) + mass[:, 0])}


def dive_normalised(scores: np.ndarray, dives: Sequence[str]) -> np.ndarray:
    """Each dive's scores as ranks in (0, 1) within that dive: what per-dive normalisation can do at best."""
    out = np.empty_like(scores, dtype=np.float64)
    dives = np.asarray(dives)
    for d in dict.fromkeys(dives):
        idx = np.flatnonzero(dives == d)
        order = scores[idx].argsort().argsort()
        out[idx] = (order + 0.5) / len(idx)
    return out


def sweep(frames: Sequence[LabelledFrame], backbones: Sequence[str] = ("lite0", "lite1", "lite2"),
          colours: Sequence[str] = ("none", "grayworld"),
          progress: Callable[[str], None] = lambda _: None) -> dict[str, np.ndarray]:
    """{variant name: score per frame}."""
    images = [f.image for f in frames]
    dives = [f.source for f in frames]
    out: dict[str, np.ndarray] = {}
    for backbone in backbones:
        for colour in colours:
            progress(f"{backbone}/{colour}")
            enc = ImageNetEncoder(EncoderConfig(name="imagenet"), backbone=backbone, colour=colour)
            emb = enc.encode_images(images)
            probs = emb[:, FEATURES:].reshape(len(images), -1, CLASSES)
            for vocab, mask in _vocabularies().items():
                mass = np.clip(probs @ mask, 0.0, 1.0)
                for view, s in _views(mass).items():
                    name = f"{backbone}/{colour}/{view}/{vocab}"
                    out[name] = s.astype(np.float64)
                    out[name + "/dive-norm"] = dive_normalised(s, dives)
    return out
