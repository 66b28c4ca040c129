"""How well a semantic score ranks labelled positive frames above negatives (area under the ROC curve).

AUROC is the probability that a random positive frame scores higher than a random negative one (ties count
half): 1 is a perfect ranking, 0.5 is chance. It is threshold-free, so it judges the encoder and the prompts
apart from the choice of tau_ss. Computed with the Mann-Whitney rank sum (average ranks for ties).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.errors import MerlionError


def auroc(scores: Sequence[float], positive: Sequence[bool]) -> float:
    """Area under the ROC curve of ``scores`` for the binary labels ``positive``."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    if s.shape != y.shape or s.ndim != 1:
        raise MerlionError(f"auroc: {len(s)} scores but {len(y)} labels")
    n_pos = int(y.sum())
    n_neg = len(y) - n_pos
    if n_pos == 0 or n_neg == 0:
        raise MerlionError(f"auroc: needs both positive and negative frames (got {n_pos} positive, {n_neg} negative)")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s), dtype=np.float64)
    sorted_s = s[order]
    i = 0
    while i < len(s):
        j = i
        while j + 1 < len(s) and sorted_s[j + 1] == sorted_s[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def threshold_rates(scores: Sequence[float], positive: Sequence[bool], tau: float) -> dict[str, float]:
    """What a threshold does: share of positives kept (recall) and of negatives let through (false-pass rate)."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    passed = s > tau
    return {
        "tau": float(tau),
        "recall": float(passed[y].mean()) if y.any() else float("nan"),
        "false_pass": float(passed[~y].mean()) if (~y).any() else float("nan"),
        "precision": float(y[passed].mean()) if passed.any() else float("nan"),
    }
