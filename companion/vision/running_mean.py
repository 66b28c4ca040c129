"""A causal running mean of one dive's values: plain over the first ``tau`` frames, exponential after.

Shared by the dive window (pooled features, ``dive_mean``) and the scene memory (view features, ``scene_memory``),
and by the evaluation that centres scores the same way (``companion.evaluation.dive_centring``).
"""

from __future__ import annotations

import numpy as np

TAU = 100.0
"""Frames over which the dive's mean forgets (an exponential mean past the first ``TAU`` frames), and the number
of recent frames kept. On the shared data's 60-frame DeepFish habitats 30, 100 and 300 gave AUROCs within 0.001
of each other (docs/evaluation.md)."""


class RunningMean:
    """The causal mean of one dive's values (scalars or feature vectors), starting from a prior."""

    def __init__(self, prior: float | np.ndarray, prior_weight: float, tau: float = TAU) -> None:
        if prior_weight < 0 or tau < 1:
            raise ValueError(f"prior_weight must be >= 0 and tau >= 1, got {prior_weight}, {tau}")
        self.mean = np.array(prior, dtype=np.float64, copy=True)
        self.weight = float(prior_weight)
        self.tau = float(tau)

    def centre(self, value: float | np.ndarray) -> float | np.ndarray:
        """Take in one frame's value and return it minus the mean of the dive so far (this frame included)."""
        return _plain(self._join(value) - self.mean)

    def take(self, value: float | np.ndarray) -> float | np.ndarray:
        """Take in one frame's value and return it minus the mean of the dive before it.

        What sets a frame apart from its scene: a frame is not its own background. Centred on a mean that holds it,
        a dive's second frame shows half its change, its third two thirds, so a short dive's early rows are shrunk
        against its later ones (measured on the scene head: docs/encoders.md, "A frame against the dive before it").
        """
        before = self.mean
        return _plain(self._join(value) - before)

    def _join(self, value: float | np.ndarray) -> np.ndarray:
        """The frame's value taken into the mean (plain up to ``tau`` frames, exponential after), as an array."""
        x = np.asarray(value, dtype=np.float64)
        self.weight += 1.0
        rate = max(1.0 / self.weight, 1.0 / self.tau)
        self.mean = self.mean + rate * (x - self.mean)
        return x


def _plain(out: np.ndarray) -> float | np.ndarray:
    """A scalar dive's difference as a float, a feature vector's as the array."""
    return float(out) if out.ndim == 0 else out
