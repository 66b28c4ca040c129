"""What the dive has looked like so far: a causal running mean of the frames' pooled features, and the last frames.

Every frame of a dive shares its water, light and sea bed; a frame's features minus the dive's running mean keep
what sets it apart from its own dive (a fish) and drop what it shares with the dive's other frames. The operator's
marks (``companion.vision.feedback``) are compared in that centred space, so three marks from a dive's first
minutes teach the object and not the scene.

The frames and their pooled features are the same for every topic, so one ``DiveWindow`` serves them all: whatever
runs every topic over one encoder pass (``Pipeline``, the live raw gate, ``merlion score``) owns it, feeds it each
batch once (``DiveWindow.take``) and hands every topic's pre-sampler the result (``DiveFrames``); each pre-sampler
reads the window and keeps only what is its own, its query's log-odds over the recent frames (``QueryWindow``). A
pre-sampler used alone owns a window of its own. A new run of the companion is a new dive.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from companion.vision.running_mean import TAU, RunningMean
from companion.vision.scene_memory import SceneInput, SceneMemory


def logit(scores: np.ndarray) -> np.ndarray:
    """Query scores in (0, 1) as log-odds, clipped so a saturated 0 or 1 stays finite."""
    p = np.clip(np.asarray(scores, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


@dataclass(frozen=True)
class DiveFrames:
    """One batch as its dive saw it, handed to every topic's pre-sampler."""

    pooled: np.ndarray
    """(N, D) the encoder's pooled (sampler) features, as it gives them."""
    centred: np.ndarray
    """(N, D) float64: each row minus the dive's mean; up to and including that frame when it joined the dive,
    else the mean as it stands."""
    joined: bool
    """The frames joined the dive (False: a frame scored again, e.g. its enhanced copy)."""
    scene: np.ndarray | None = None
    """(N, D) each frame's scene residual (``scene_memory``; NaN rows: no scene before the frame), when the owner
    gave the scene input; None: the frames are not judged against the dive's scene."""
    embeddings: np.ndarray | None = None
    """(N, E) the frames' own embeddings, where the owner kept them: copies judged by these rows (``copies``) are
    compared with the marks as their frames were (``Encoder.object_features``), not by the enhancer's colours."""

    def rows(self, index: Sequence[int] | np.ndarray) -> DiveFrames:
        """These frames only, in this order (a gate's subset; one candidate's row)."""
        index = np.asarray(index, dtype=int)
        return DiveFrames(self.pooled[index], self.centred[index], self.joined,
                          None if self.scene is None else self.scene[index],
                          None if self.embeddings is None else self.embeddings[index])

    @staticmethod
    def stack(parts: Sequence[DiveFrames]) -> DiveFrames:
        """Rows taken at different times (the candidates of one enhancer batch) as one batch; scene rows and
        embeddings only when every part has them."""
        def concatenated(name: str) -> np.ndarray | None:
            rows = [getattr(p, name) for p in parts]
            return None if any(r is None for r in rows) else np.concatenate(rows)

        return DiveFrames(concatenated("pooled"), concatenated("centred"), all(p.joined for p in parts),
                          concatenated("scene"), concatenated("embeddings"))

    def copies(self) -> DiveFrames:
        """These frames' copies (their enhanced versions), judged by the frames' own place in the dive: their
        pooled and centred features, scene residuals and embeddings, never joining it."""
        return replace(self, joined=False)


class DiveWindow:
    """One dive's running mean of pooled features, and the last ``tau`` frames' centred features (what the marks'
    score is scaled against); fed once per frame by its owner, read by every topic."""

    def __init__(self, tau: float = TAU) -> None:
        self.tau = tau
        self._mean: RunningMean | None = None
        self.recent: deque[np.ndarray] = deque(maxlen=int(tau))
        self.frames = 0
        """Frames taken in so far."""
        self.scene = SceneMemory(tau)
        """The dive's scene, region by region (for a head that reads the scene residual)."""

    @property
    def seen(self) -> bool:
        return self._mean is not None

    @property
    def mean(self) -> np.ndarray | None:
        """The dive's mean so far (None before the first frame)."""
        return None if self._mean is None else self._mean.mean

    def add(self, features: np.ndarray) -> np.ndarray:
        """Take in a batch in frame order; each row minus the dive's mean up to and including that frame."""
        f = np.asarray(features, dtype=np.float64)
        out = np.zeros_like(f)
        for i, row in enumerate(f):
            if self._mean is None:
                self._mean = RunningMean(row, 0.0, self.tau)
            out[i] = self._mean.centre(row)
            self.recent.append(out[i])
        self.frames += len(f)
        return out

    def offsets(self, features: np.ndarray) -> np.ndarray:
        """Rows minus the dive's mean as it stands, without taking them in (zeros before the first frame)."""
        f = np.asarray(features, dtype=np.float64)
        return np.zeros_like(f) if self._mean is None else f - self._mean.mean

    def take(self, pooled: np.ndarray, join: bool = True, scene: SceneInput | None = None,
             embeddings: np.ndarray | None = None) -> DiveFrames:
        """A batch's pooled features for every topic: taken into the dive (``join``), or only centred by it; with
        ``scene`` (``Encoder.scene_input``) also each frame's scene residual; ``embeddings`` are carried along."""
        residuals = None if scene is None else self.scene.residuals(scene, join=join)
        return DiveFrames(pooled, self.add(pooled) if join else self.offsets(pooled), join, residuals, embeddings)

    def recent_features(self) -> np.ndarray:
        """(frames, features) centred features of the last ``tau`` frames ((0, 0) before the first)."""
        return np.stack(self.recent) if self.recent else np.zeros((0, 0))


class QueryWindow:
    """One topic's query log-odds over the dive's last ``tau`` frames: the spread its marks are scaled to."""

    def __init__(self, tau: float = TAU) -> None:
        self.recent: deque[float] = deque(maxlen=int(tau))

    def add(self, query_scores: np.ndarray) -> None:
        self.recent.extend(float(q) for q in logit(query_scores))

    def values(self) -> np.ndarray:
        return np.array(self.recent, dtype=np.float64)
