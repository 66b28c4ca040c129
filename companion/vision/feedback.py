"""The operator's marked examples ("more like this" / "not this") combined with the text or concept score.

No text query knows what this operator wants on this dive, and no vocabulary covers every target; a few marked
frames do. They are embedded with the encoder's own sampler features (CLIP's image embedding, the packaged
encoder's pooled features), and a nearest-centroid rule scores every frame: ``d = (f - mid) . w / (|w|^2 / 2)``
with ``w = like - unlike`` (the two prototypes), so ``d`` is +1 at the "like" prototype, -1 at the "unlike"
one and 0 half way, whatever the feature scale. With marks on one side only, the other prototype is the running
mean of the frames scored so far ("not this" = "what this dive usually looks like").

The combined score is ``(1 - w) * text + w * sigmoid(GAIN * d)`` with ``w = n / (n + 2)`` for n marks: one
mark of each kind weighs as much as the query, five of each 0.83. It stays in (0, 1), so tau_ss keeps its
meaning. The same ``MarkedPreSampler`` serves ``merlion score``, ``merlion summarize`` and the live companion.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.errors import UsageError
from companion.sources.folder import collect_images
from companion.vision.encoders.base import Encoder
from companion.vision.presampler import PreSampler

GAIN = 3.0
"""Slope of the example score at the mid point: d = +1 (the like prototype) maps to sigmoid(3) = 0.95."""


def _normalised(features: np.ndarray) -> np.ndarray:
    f = np.asarray(features, dtype=np.float64)
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-12)


@dataclass
class Marks:
    """Sampler features of the marked frames, L2-normalised, one row per mark."""

    like: np.ndarray
    unlike: np.ndarray

    def __len__(self) -> int:
        return len(self.like) + len(self.unlike)

    @classmethod
    def from_features(cls, like: np.ndarray, unlike: np.ndarray) -> Marks:
        dim = like.shape[-1] if len(like) else unlike.shape[-1]
        return cls(_normalised(np.reshape(like, (len(like), dim))), _normalised(np.reshape(unlike, (len(unlike), dim))))

    @classmethod
    def from_images(cls, encoder: Encoder, like: Sequence[np.ndarray], unlike: Sequence[np.ndarray]) -> Marks:
        def feats(images: Sequence[np.ndarray]) -> np.ndarray:
            if not images:
                return np.zeros((0, 1))
            return encoder.sampler_features(encoder.encode_images(list(images)))

        return cls.from_features(feats(like), feats(unlike))


@dataclass
class ExampleScorer:
    """Nearest-centroid score of frames against the marks, in (0, 1); 0.5 half way between the prototypes."""

    marks: Marks
    _seen_sum: np.ndarray | None = field(default=None, repr=False)
    _seen: int = 0

    def observe(self, features: np.ndarray) -> None:
        """Add frames to the running mean that stands in for a missing side."""
        f = _normalised(features)
        self._seen_sum = f.sum(axis=0) if self._seen_sum is None else self._seen_sum + f.sum(axis=0)
        self._seen += len(f)

    def _prototype(self, rows: np.ndarray) -> np.ndarray | None:
        if len(rows):
            return rows.mean(axis=0)
        if self._seen:
            return self._seen_sum / self._seen
        return None

    def scores(self, features: np.ndarray) -> np.ndarray:
        f = _normalised(features)
        like, unlike = self._prototype(self.marks.like), self._prototype(self.marks.unlike)
        if like is None or unlike is None:
            return np.full(len(f), 0.5)
        w = like - unlike
        half = float(w @ w) / 2.0
        if half < 1e-12:
            return np.full(len(f), 0.5)
        d = (f - (like + unlike) / 2.0) @ w / half
        return 1.0 / (1.0 + np.exp(-GAIN * d))


def mark_weight(n: int) -> float:
    """Share of the combined score given to the marks: n / (n + 2)."""
    return n / (n + 2.0)


class MarkedPreSampler(PreSampler):
    """The pre-sampler with marks: same queries and tau_ss, score combined with the examples."""

    def __init__(self, base: PreSampler, marks: Marks) -> None:
        self.encoder = base.encoder
        self.tau_ss = base.tau_ss
        self.positive, self.negatives, self.text_embeddings = base.positive, base.negatives, base.text_embeddings
        self.set_marks(marks)

    def set_marks(self, marks: Marks) -> None:
        self.examples = ExampleScorer(marks)
        self.weight = mark_weight(len(marks))

    def text_scores(self, image_embeddings: np.ndarray) -> np.ndarray:
        return super().scores(image_embeddings)

    def scores(self, image_embeddings: np.ndarray) -> np.ndarray:
        text = self.text_scores(image_embeddings)
        if len(image_embeddings) == 0 or self.weight == 0.0:
            return text
        feats = self.encoder.sampler_features(image_embeddings)
        self.examples.observe(feats)
        ex = self.examples.scores(feats)
        return ((1.0 - self.weight) * text + self.weight * ex).astype(np.float32)


def read_mark_images(paths: Sequence[str | Path], option: str) -> list[np.ndarray]:
    """Images named by --like/--unlike (a folder means every image in it); one-line errors name the file."""
    images = []
    for path in collect_images(paths):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise UsageError(f"{option} {path}: cannot decode as an image")
        images.append(img)
    return images


def with_marks(presampler: PreSampler, like: Sequence[np.ndarray], unlike: Sequence[np.ndarray]) -> PreSampler:
    """The pre-sampler to use given the marked images (unchanged when there are none)."""
    if not like and not unlike:
        return presampler
    return MarkedPreSampler(presampler, Marks.from_images(presampler.encoder, like, unlike))
