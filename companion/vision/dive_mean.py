"""What the dive has looked like so far: a causal running mean of the frames' pooled features, and the last frames.

Every frame of a dive shares its water, light and sea bed; a frame's features minus the dive's running mean keep
what sets it apart from its own dive (a fish) and drop what it shares with the dive's other frames. The operator's
marks (``companion.vision.feedback``) are compared in that centred space, so three marks from a dive's first
minutes teach the object and not the scene. The pre-sampler that scores a dive owns one ``DiveWindow`` and feeds
it every frame it scores; a new run of the companion is a new dive.
"""

from __future__ import annotations

from collections import deque

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
        self.weight += 1.0
        rate = max(1.0 / self.weight, 1.0 / self.tau)
        self.mean = self.mean + rate * (np.asarray(value, dtype=np.float64) - self.mean)
        out = np.asarray(value, dtype=np.float64) - self.mean
        return float(out) if out.ndim == 0 else out


def logit(scores: np.ndarray) -> np.ndarray:
    """Query scores in (0, 1) as log-odds, clipped so a saturated 0 or 1 stays finite."""
    p = np.clip(np.asarray(scores, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


class DiveWindow:
    """One dive's running mean of pooled features, and the last ``tau`` frames' centred features and query
    log-odds (what the marks' score is scaled against)."""

    def __init__(self, tau: float = TAU) -> None:
        self.tau = tau
        self._mean: RunningMean | None = None
        self.recent: deque[tuple[np.ndarray, float]] = deque(maxlen=int(tau))

    @property
    def seen(self) -> bool:
        return self._mean is not None

    @property
    def mean(self) -> np.ndarray | None:
        """The dive's mean so far (None before the first frame)."""
        return None if self._mean is None else self._mean.mean

    def add(self, features: np.ndarray, query_scores: np.ndarray) -> np.ndarray:
        """Take in a batch in frame order; each row minus the dive's mean up to and including that frame."""
        f = np.asarray(features, dtype=np.float64)
        out = np.zeros_like(f)
        for i, (row, q) in enumerate(zip(f, logit(query_scores), strict=True)):
            if self._mean is None:
                self._mean = RunningMean(row, 0.0, self.tau)
            out[i] = self._mean.centre(row)
            self.recent.append((out[i], float(q)))
        return out

    def offsets(self, features: np.ndarray) -> np.ndarray:
        """Rows minus the dive's mean as it stands, without taking them in (zeros before the first frame)."""
        f = np.asarray(features, dtype=np.float64)
        return np.zeros_like(f) if self._mean is None else f - self._mean.mean

    def recent_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(frames, features) centred features and (frames,) query log-odds of the last ``tau`` frames."""
        if not self.recent:
            return np.zeros((0, 0)), np.zeros(0)
        return np.stack([f for f, _ in self.recent]), np.array([q for _, q in self.recent])
