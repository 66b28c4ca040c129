"""The online informative sampler: keep the K most mutually different relevant frames seen so far.

Exactly REFERENCE.md section 1, steps 2-7:

- features are the absolute, L2-normalised embeddings (``companion.vision.distances.prepare_features``);
- a frame that is a duplicate of a member (cosine distance of the prepared features at most
  ``DUPLICATE_COSINE``) never enters, not even during warm-up: a summary never holds the same picture twice, and
  when a dive has fewer distinct views than K the summary stays smaller;
- the first K (distinct) frames offered enter unconditionally (warm-up);
- afterwards a frame enters only if its surprise ``alpha = min_i d(v, S_i)`` is strictly greater than the
  threshold ``gamma`` (by default the mean over members of the distance to their nearest other member);
- after an entry the summary is trimmed back to K by greedy farthest-point selection seeded with the newest frame
  (Girdhar's K-OnlineSummaryUpdate); ties go to the member inserted earliest.

The summary's pairwise distance matrix ``D[i, j] = d(S_i, S_j)`` is kept (members in insertion order), so testing a
frame costs one O(K x D) distance pass and only an entry costs the O(K^2) trim. Everything is deterministic.
K, the distance and the threshold rule can change while running (live tuning); a summary can be restored from
stored (key, feature) pairs so a rebooted companion resumes with the same frames.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from companion.vision import distances as dist

THRESHOLDS = ("mean", "min", "2min", "median")
DUPLICATE_COSINE = 6e-3
"""Two frames whose prepared features are at most this cosine distance apart are the same picture.

Measured (issue 25; ``1 - cos`` of the prepared features, the packaged ImageNet encoder / the visual encoder):
the frames of one still held 2 s in a video written by OpenCV's mp4v codec differ by up to 4.7e-3 / 5.6e-3
(the codec's noise from one group of pictures to the next), a looped clip's repeated frames by 0; two frames at
least 1 s apart in the survey video, the aquarium clip or the ROV clips differ by at least 1.8e-2 (ImageNet;
the weaker visual encoder 4.6e-3 on the survey's slow ROV segments). Only frames well under a second apart in a
slow scene fall below it. Cosine rather than the sampler's own distance, so the rule is the same whichever
distance is configured. CLIP was not measured (no weights here)."""


@dataclass
class Decision:
    """What the sampler did with one offered frame."""

    added: bool
    key: int
    alpha: float
    """min_i d(v, S_i); inf when the summary was empty."""
    gamma: float
    """The threshold the frame was compared against (NaN during warm-up)."""
    warmup: bool
    removed: list[int] = field(default_factory=list)
    """Keys trimmed out because this frame entered."""
    duplicate: bool = False
    """Refused because it is the same picture as a member (``DUPLICATE_COSINE``)."""


class InformativeSampler:
    """Online K-summary over sampler features; members are identified by integer keys chosen by the caller."""

    def __init__(self, k: int = 6, distance: str = "js", threshold: str = "mean",
                 duplicate_cosine: float = DUPLICATE_COSINE) -> None:
        self._check(k, distance, threshold)
        self.k = k
        self.duplicate_cosine = duplicate_cosine
        """Frames at most this cosine distance from a member are the same picture (the encoder may say)."""
        self.distance = distance
        self.threshold = threshold
        self._keys: list[int] = []
        self._feat = np.zeros((0, 0), dtype=np.float64)
        self._h = np.zeros(0, dtype=np.float64)
        self._dm = np.zeros((0, 0), dtype=np.float64)
        self._gamma: float | None = None

    @staticmethod
    def _check(k: int, distance: str, threshold: str) -> None:
        if int(k) < 1:
            raise ValueError(f"sampler k must be at least 1, got {k}")
        if distance not in dist.DISTANCES:
            raise ValueError(f"unknown sampler distance {distance!r}; choose one of {', '.join(dist.DISTANCES)}")
        if threshold not in THRESHOLDS:
            raise ValueError(f"unknown sampler threshold {threshold!r}; choose one of {', '.join(THRESHOLDS)}")

    # ----- what is held -------------------------------------------------------------------------------------

    @property
    def keys(self) -> list[int]:
        """Member keys in insertion order."""
        return list(self._keys)

    @property
    def features(self) -> np.ndarray:
        """Member features (len(keys), D), rows in insertion order."""
        return self._feat.copy()

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def distance_matrix(self) -> np.ndarray:
        return self._dm.copy()

    @property
    def gamma(self) -> float:
        """The current threshold (0 with fewer than two members: nothing to compare with)."""
        if self._gamma is None:
            self._gamma = self._compute_gamma()
        return self._gamma

    def _compute_gamma(self) -> float:
        n = len(self._keys)
        if n < 2:
            return 0.0
        masked = self._dm + np.diag(np.full(n, np.inf))
        nn = masked.min(axis=1)
        if self.threshold == "mean":
            return float(nn.mean())
        if self.threshold == "min":
            return float(nn.min())
        if self.threshold == "2min":
            return float(2.0 * nn.min())
        return float(np.median(nn))

    # ----- distances ----------------------------------------------------------------------------------------

    def _to_members(self, v: np.ndarray, v_h: float) -> np.ndarray:
        """d(v, S_i) for every member."""
        if self.distance == "js":
            return dist.js_many(v, self._feat, v_h, self._h)
        if self.distance == "kl":
            return dist.kl_many(v, self._feat, v_h)
        return dist.cosine_many(v, self._feat)

    def _from_members(self, v: np.ndarray, row: np.ndarray) -> np.ndarray:
        """d(S_i, v) for every member (the same as ``row`` unless the distance is asymmetric)."""
        if self.distance == "kl":
            return dist.kl_many_reverse(v, self._feat, self._h)
        return row

    # ----- the method ---------------------------------------------------------------------------------------

    def offer(self, key: int, embedding: np.ndarray, *, prepared: bool = False) -> Decision:
        """Test one frame and update the summary.

        ``embedding`` is a raw sampler embedding, or with ``prepared=True`` a feature already made absolute and
        L2-normalised by ``distances.prepare_features`` (float64), which the pipeline does once per batch.
        """
        if prepared:
            v = np.asarray(embedding, dtype=np.float64).reshape(-1)
        else:
            v = dist.prepare_features(np.asarray(embedding).reshape(-1))
        if len(self._keys) and v.shape[0] != self._feat.shape[1]:
            raise ValueError(f"feature has {v.shape[0]} dimensions, the summary holds {self._feat.shape[1]}")
        v_h = float(dist.xlogx_sum(v))
        if not self._keys:
            self._insert(key, v, v_h, np.zeros(0), np.zeros(0))
            return Decision(True, key, float("inf"), float("nan"), True)
        row = self._to_members(v, v_h)
        alpha = float(row.min())
        if float(dist.cosine_many(v, self._feat).min()) <= self.duplicate_cosine:
            return Decision(False, key, alpha, float("nan"), len(self._keys) < self.k, duplicate=True)
        if len(self._keys) < self.k:
            self._insert(key, v, v_h, row, self._from_members(v, row))
            return Decision(True, key, alpha, float("nan"), True)
        gamma = self.gamma
        if not alpha > gamma:
            return Decision(False, key, alpha, gamma, False)
        self._insert(key, v, v_h, row, self._from_members(v, row))
        removed = self._trim(self.k)
        return Decision(True, key, alpha, gamma, False, removed)

    def _insert(self, key: int, v: np.ndarray, v_h: float, row: np.ndarray, col: np.ndarray) -> None:
        n = len(self._keys)
        dm = np.zeros((n + 1, n + 1), dtype=np.float64)
        dm[:n, :n] = self._dm
        dm[n, :n] = row
        dm[:n, n] = col
        self._dm = dm
        self._feat = v[None, :].copy() if n == 0 else np.vstack([self._feat, v[None, :]])
        self._h = np.append(self._h, v_h)
        self._keys.append(int(key))
        self._gamma = None

    def _trim(self, k: int) -> list[int]:
        """Greedy farthest-point selection seeded with the newest member; returns the removed keys."""
        n = len(self._keys)
        if n <= k:
            return []
        newest = n - 1
        chosen = [newest]
        taken = np.zeros(n, dtype=bool)
        taken[newest] = True
        # distance of every member to the new summary: min over chosen s of d(member, s)
        to_new = self._dm[:, newest].copy()
        for _ in range(k - 1):
            candidates = np.where(taken, -np.inf, to_new)
            j = int(np.argmax(candidates))  # first maximum = earliest inserted
            chosen.append(j)
            taken[j] = True
            np.minimum(to_new, self._dm[:, j], out=to_new)
        keep = np.flatnonzero(taken)
        removed = [self._keys[i] for i in range(n) if not taken[i]]
        self._keys = [self._keys[i] for i in keep]
        self._feat = self._feat[keep]
        self._h = self._h[keep]
        self._dm = self._dm[np.ix_(keep, keep)]
        self._gamma = None
        return removed

    # ----- live tuning and resume ---------------------------------------------------------------------------

    def set_k(self, k: int) -> list[int]:
        """Change K now; a smaller K trims at once (seeded with the newest member) and returns the removed keys.

        A larger K leaves the summary not full, so the next frames enter as in warm-up until it holds K.
        """
        self._check(k, self.distance, self.threshold)
        self.k = int(k)
        return self._trim(self.k)

    def configure(self, *, distance: str | None = None, threshold: str | None = None) -> None:
        """Change the distance or threshold rule; the kept distance matrix is recomputed when needed."""
        distance = distance or self.distance
        threshold = threshold or self.threshold
        self._check(self.k, distance, threshold)
        changed = distance != self.distance
        self.distance, self.threshold = distance, threshold
        if changed and self._keys:
            self._dm = dist.pairwise(self._feat, self.distance)
        self._gamma = None

    def restore(self, members: Iterable[tuple[int, np.ndarray]]) -> list[int]:
        """Replace the summary with stored (key, feature) pairs, given in their original insertion order.

        More than K pairs are trimmed as after an entry (the last pair counts as the newest); returns those removed.
        """
        pairs = list(members)
        self._keys = [int(key) for key, _ in pairs]
        if not pairs:
            self._feat = np.zeros((0, 0), dtype=np.float64)
            self._h = np.zeros(0, dtype=np.float64)
            self._dm = np.zeros((0, 0), dtype=np.float64)
        else:
            self._feat = dist.prepare_features(np.stack([np.asarray(f).reshape(-1) for _, f in pairs]))
            self._h = dist.xlogx_sum(self._feat)
            self._dm = dist.pairwise(self._feat, self.distance)
        self._gamma = None
        return self._trim(self.k)
