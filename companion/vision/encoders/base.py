"""The one small interface every image encoder offers the pipeline.

The pipeline never knows which encoder it holds: it encodes a batch of frames, scores them against the
queries, and hands the sampler features. Encoders differ in how a score is computed (CLIP: softmax of
100 x cosine; the packaged ImageNet encoder: concept probability mass), so scoring is the encoder's job.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from companion.vision.scene_memory import SceneInput


class Encoder(ABC):
    name: str
    """e.g. "clip:ViT-B-32", "imagenet:efficientnet-lite0", "visual"."""
    duplicate_cosine: float | None = None
    """How close (cosine of sampler features) two frames must be to count as the same picture; None: the
    sampler's measured default (``companion.vision.sampler.DUPLICATE_COSINE``)."""

    @property
    @abstractmethod
    def input_size(self) -> tuple[int, int]:
        """(width, height) the encoder wants; the pipeline may downscale frames to about this before encoding."""

    @abstractmethod
    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """BGR uint8 frames (any size) -> (N, D) float32 image embeddings."""

    @abstractmethod
    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """Query texts -> (M, D') float32 query embeddings; raises MerlionError for a query it cannot answer."""

    @abstractmethod
    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        """(N,) scores in (0, 1): the share of the first (positive) query, as REFERENCE.md section 1 defines."""

    def sampler_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        """The part of the embedding the informative sampler compares (all of it unless an encoder says otherwise)."""
        return image_embeddings

    def object_features(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        """Features of the part of each frame that looks most like the positive query, for the operator's marks
        (the object, not the scene); encoders without regions give their sampler features."""
        return self.sampler_features(image_embeddings)

    def scene_input(self, image_embeddings: np.ndarray) -> SceneInput | None:
        """What the dive's scene memory compares (``companion.vision.scene_memory``: view features and small
        frames); None for an encoder whose scores do not use it."""
        return None

    def with_scene(self, image_embeddings: np.ndarray, residuals: np.ndarray) -> np.ndarray:
        """The embeddings with each frame's scene residual (from ``scene_input``) in place, for
        ``semantic_scores``; unchanged for an encoder that does not use it."""
        return image_embeddings

    def describe(self) -> dict:
        """What went into the scores (architecture, weights, precision, device), for summary.json and status."""
        return {"name": self.name}
