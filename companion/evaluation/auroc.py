"""How well a semantic score ranks labelled positive frames above negatives, for ``merlion eval auroc``.

AUROC is threshold-free, so it judges the encoder and the prompts apart from the choice of tau_ss; the area
itself comes from ``companion.evaluation.roc`` (the encoder area's implementation, shared rather than duplicated). This
module adds the one-line error the command line wants and what a given threshold does to the same frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.errors import MerlionError
from companion.evaluation import roc as _auroc


def auroc(scores: Sequence[float], positive: Sequence[bool]) -> float:
    """Area under the ROC curve (1 perfect, 0.5 chance); MerlionError when it is undefined."""
    try:
        return _auroc.auroc(scores, positive)
    except ValueError as err:
        raise MerlionError(str(err)) from None


def threshold_rates(scores: Sequence[float], positive: Sequence[bool], tau: float) -> dict[str, float]:
    """What a threshold does: share of positives kept (recall), of negatives let through, and precision."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    passed = s > tau
    return {
        "tau": float(tau),
        "recall": float(passed[y].mean()) if y.any() else float("nan"),
        "false_pass": float(passed[~y].mean()) if (~y).any() else float("nan"),
        "precision": float(y[passed].mean()) if passed.any() else float("nan"),
    }
