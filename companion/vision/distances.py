"""Distances between sampler features, one query vector against many summary members at once.

The sampler compares every frame with the K summary members, so each function takes one vector ``v`` (D,) and
a matrix ``S`` (K, D) and returns the K distances ``d(v, S_i)`` in one vectorised pass: O(K x D), no Python loop.
Features are the element-wise absolute, L2-normalised embeddings (REFERENCE.md section 1 step 2), so they are
non-negative; the divergences treat them as the paper does, without renormalising them to sum 1.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

KL_FLOOR = 1e-12
"""KL(p || q) is infinite where q_i = 0 < p_i; q is floored at this value so ROST's KL option stays finite."""

DISTANCES = ("js", "kl", "cosine")


def prepare_features(embeddings: np.ndarray) -> np.ndarray:
    """Embeddings -> sampler features: element-wise absolute value, then L2 normalisation (float64).

    Idempotent, so stored features can be passed through it again on restore.
    """
    x = np.abs(np.asarray(embeddings, dtype=np.float64))
    norms = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.where(norms > 0.0, norms, 1.0)


def xlogx_sum(x: np.ndarray) -> np.ndarray:
    """Sum over the last axis of x * log(x), with 0 * log 0 = 0."""
    logs = np.log(x, out=np.zeros_like(x), where=x > 0.0)
    return np.einsum("...d,...d->...", x, logs)


def js_many(v: np.ndarray, members: np.ndarray, v_h: float | None = None, members_h: np.ndarray | None = None) -> np.ndarray:
    """Jensen-Shannon divergence JS(v, S_i) = 1/2 KL(v||m) + 1/2 KL(S_i||m), m = (v + S_i) / 2.

    Uses the identity JS = (h(v) + h(S_i)) / 2 - h(m) with h(x) = sum x log x; ``v_h`` and ``members_h`` are
    those sums when the caller already has them (the sampler caches them per member).
    """
    if v_h is None:
        v_h = float(xlogx_sum(v))
    if members_h is None:
        members_h = xlogx_sum(members)
    m = 0.5 * (members + v[None, :])
    out = 0.5 * (v_h + members_h) - xlogx_sum(m)
    return np.maximum(out, 0.0)


def kl_many(v: np.ndarray, members: np.ndarray, v_h: float | None = None) -> np.ndarray:
    """KL(v || S_i) = sum v log(v / S_i) (ROST's distance), with S_i floored at KL_FLOOR and 0 log 0 = 0."""
    if v_h is None:
        v_h = float(xlogx_sum(v))
    cross = np.log(np.maximum(members, KL_FLOOR)) @ v
    return np.maximum(v_h - cross, 0.0)


def kl_many_reverse(v: np.ndarray, members: np.ndarray, members_h: np.ndarray) -> np.ndarray:
    """KL(S_i || v) for every member: the other direction, needed when v joins the summary."""
    cross = members @ np.log(np.maximum(v, KL_FLOOR))
    return np.maximum(members_h - cross, 0.0)


def cosine_many(v: np.ndarray, members: np.ndarray) -> np.ndarray:
    """1 - cos(v, S_i); features are unit vectors, so this is 1 - dot product."""
    return np.maximum(1.0 - members @ v, 0.0)


def pairwise(features: np.ndarray, distance: str) -> np.ndarray:
    """Full matrix D[i, j] = d(S_i, S_j) (zero diagonal); used when a summary is restored."""
    one: Callable[[np.ndarray], np.ndarray]
    h = xlogx_sum(features)
    if distance == "js":
        def one(i: int) -> np.ndarray:
            return js_many(features[i], features, float(h[i]), h)
    elif distance == "kl":
        def one(i: int) -> np.ndarray:
            return kl_many(features[i], features, float(h[i]))
    elif distance == "cosine":
        def one(i: int) -> np.ndarray:
            return cosine_many(features[i], features)
    else:
        raise ValueError(f"unknown distance {distance!r}; choose one of {', '.join(DISTANCES)}")
    n = len(features)
    out = np.zeros((n, n), dtype=np.float64)
    for i in range(n):
        out[i] = one(i)
    np.fill_diagonal(out, 0.0)
    return out
