"""What sets a frame apart from its dive's scene, region by region: the scene-residual features.

A fixed camera or a slow ROV sees the same water, light and sea bed for minutes; what a fish adds is local and
comes and goes. Each frame's view features (the whole frame and its regions, ``Encoder.scene_views``) minus the
dive's causal running mean of the same views, kept where positive (something there that this part of the scene
usually lacks) and averaged over the views, give one vector per frame. A learned head on it (a head with input
"scene", ``learned_head``) ranks fish frames against empty ones far better across dives than a head on the plain
pooled features, because what every frame of a dive shares (its colour cast, its sea bed) is gone: pooled
leave-one-group-out AUROC 0.73 -> 0.85 on the shared data (docs/encoders.md).

The first frame of a dive has no scene to be judged against: its residual is NaN, and the head on the pooled
features scores it (as it does a frame scored before any dive, e.g. one image). After that the mean, this frame
included, is plain up to ``tau`` frames and exponential past them (``running_mean``). The dive window (``dive_mean.DiveWindow``) owns one per dive.
"""

from __future__ import annotations

import numpy as np

from companion.vision.running_mean import TAU, RunningMean


class SceneMemory:
    """One dive's running mean of the view features (V, D), and each frame's positive residual from it."""

    def __init__(self, tau: float = TAU) -> None:
        self.tau = tau
        self._mean: RunningMean | None = None

    @property
    def seen(self) -> bool:
        return self._mean is not None

    def residuals(self, views: np.ndarray, *, join: bool = True) -> np.ndarray:
        """(N, V, D) views of frames in order -> (N, D) mean over views of ``max(view - dive mean, 0)``, NaN
        for a frame with no scene before it.

        ``join``: each frame is taken into the mean first (this frame included, as ``RunningMean.centre``);
        without it (a frame scored again, e.g. its enhanced copy) the mean as it stands is used and kept.
        """
        v = np.asarray(views, dtype=np.float64)
        if v.ndim != 3:
            raise ValueError(f"views must be (frames, views, features), got shape {v.shape}")
        out = np.full((v.shape[0], v.shape[2]), np.nan)
        for i, row in enumerate(v):
            if self._mean is None:
                if join:
                    self._mean = RunningMean(row, 0.0, self.tau)
                    self._mean.centre(row)
                continue  # no scene before this frame: NaN, the head on the pooled features answers
            diff = self._mean.centre(row) if join else row - self._mean.mean
            out[i] = np.maximum(diff, 0.0).mean(axis=0)
        return out
