"""CLIP's semantic score, as REFERENCE.md defines it: softmax of 100 x cosine over [positive, negatives...],
the positive's share (the reference implementation's fixed scale 100, not the model's learned logit scale).

In its own torch-free module: the torch and the ONNX Runtime encoders must score identically.
"""

from __future__ import annotations

import numpy as np

SCALE = 100.0
"""REFERENCE.md: the reference implementation's fixed softmax scale."""


def positive_share(image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
    """(N,) scores in (0, 1) from L2-normalised (N, D) image and (M, D) text embeddings, positive first."""
    logits = SCALE * (image_embeddings.astype(np.float64) @ text_embeddings.astype(np.float64).T)
    logits -= logits.max(axis=1, keepdims=True)
    p = np.exp(logits)
    return (p[:, 0] / p.sum(axis=1)).astype(np.float32)
