"""An encoder that counts the images it encodes (the live companion's, and tests').

The encoder is the expensive part of a frame's way through the companion, and several topics are served by one
pass of it (issue 13 item 4). Counting at the encoder itself, rather than trusting what the pipeline says it
did, lets a test or an operator check that claim from the outside: with no enhancement and no marks, the images
encoded equal the frames scored, however many topics are followed (``/store/summary.json``'s ``encoder``).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from companion.vision.encoders.base import Encoder
from companion.vision.scene_memory import SceneInput


class CountedEncoder(Encoder):
    """Delegates everything to ``inner``; ``images`` and ``calls`` count what ``encode_images`` was given.

    Every method of ``Encoder`` is written out here: ``__getattr__`` only sees names the base class lacks, so a
    method left out would silently answer with the base class's default (as ``scene_input`` once did, which
    kept the live companion off the scene head)."""

    def __init__(self, inner: Encoder) -> None:
        self.inner = inner
        self.name = inner.name
        self.duplicate_cosine = inner.duplicate_cosine
        self.images = 0
        self.calls = 0
        self._lock = threading.Lock()  # the inference loop, the enhancer worker and marks may encode

    def __getattr__(self, attr: str) -> Any:  # what an encoder offers beyond the interface (device, views...)
        return getattr(self.__dict__["inner"], attr)

    @property
    def input_size(self) -> tuple[int, int]:
        return self.inner.input_size

    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = self.inner.encode_images(images)
        with self._lock:
            self.images += len(images)
            self.calls += 1
        return out

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        return self.inner.encode_texts(texts)

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return self.inner.semantic_scores(image_embeddings, text_embeddings)

    def sampler_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        return self.inner.sampler_features(image_embeddings)

    def object_features(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return self.inner.object_features(image_embeddings, text_embeddings)

    def scene_input(self, image_embeddings: np.ndarray) -> SceneInput | None:
        return self.inner.scene_input(image_embeddings)

    def with_scene(self, image_embeddings: np.ndarray, residuals: np.ndarray) -> np.ndarray:
        return self.inner.with_scene(image_embeddings, residuals)

    def describe(self) -> dict:
        return self.inner.describe()
