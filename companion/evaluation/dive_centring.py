"""A frame judged against its own dive: the fish head's score minus the dive's causal running mean of it.

What every frame of a dive (a DeepFish camera drop, a video) has in common is the scene: its water, light and
sea bed move the head's score of every frame alike, so a threshold or a ranking pooled over dives mixes scenes
with fish. Subtracting the running mean of the score over the frames seen so far in the same dive removes that
shift online and causally: frame t is centred by the mean of frames 0..t only, as a companion would see them.

The mean starts from a prior (the head's mean score on its training frames) that counts as ``prior_weight``
frames, so the first frames of a dive are not centred on themselves alone; after that it is the mean of all
frames seen, and past ``tau`` frames an exponential mean with time constant ``tau`` frames (a long dive drifts
from scene to scene). Whether to centre and the prior's weight are chosen with the ridge strength by nested
leave-one-group-out (``nested_centred_holdout``): never on the group reported.

Frame order: videos are streams in their own order. DeepFish's label file lists each habitat's 30 fish frames
before its 30 empty ones (its clips are all-fish or all-empty), an order that would leak the labels into a
causal mean, so each habitat's frames are streamed in a seeded random order (``stream_order``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.evaluation.head_training import (
    LAMBDAS,
    _held,
    _ridge_all,
    group_mean_auroc,
    group_names,
    held_out_scores,
)
from companion.evaluation.holdout import per_group, spread
from companion.evaluation.roc import auroc
from companion.evaluation.sources import DEEPFISH, LabelledFrame
from companion.vision.dive_mean import TAU, RunningMean

PRIOR_WEIGHTS: tuple[float | None, ...] = (None, 1.0, 5.0, 20.0)
"""Candidates for the prior's weight in frames; None: no centring. Chosen by nested leave-one-group-out."""
ORDER_SEED = 0
ORDER_SEEDS = (0, 1, 2)
"""The frame orders the evaluations that depend on the order report (seed 0 first)."""


def stream_order(frames: Sequence[LabelledFrame], seed: int = ORDER_SEED, *,
                 by_clip: bool = False) -> list[np.ndarray]:
    """Frame indices per source (one stream each), in video order; DeepFish habitats in a seeded random order.

    ``by_clip``: each clip its own stream (for the frames that name one). A DeepFish habitat's fish and empty
    frames come from different clips, so in one shuffled stream a frame's change from the dive so far is partly
    "another clip"; streamed clip by clip, no dive holds a change of clip (nor, in a fish clip, a frame without
    fish to set a fish apart from)."""
    names = np.array([f"{f.source}/{f.clip}" if by_clip and f.clip else f.source for f in frames])
    rng = np.random.default_rng(seed)
    streams = []
    for source in dict.fromkeys(names):
        idx = np.flatnonzero(names == source)
        streams.append(rng.permutation(idx) if source.startswith(DEEPFISH) else idx)
    return streams


def centred(scores: np.ndarray, streams: Sequence[np.ndarray], prior: np.ndarray, prior_weight: float | None,
            tau: float = TAU) -> np.ndarray:
    """Each frame's score minus its stream's running mean (``prior[i]``: the prior of frame i's head)."""
    if prior_weight is None:
        return np.asarray(scores, dtype=np.float64).copy()
    out = np.zeros(len(scores))
    for idx in streams:
        if len(idx):
            mean = RunningMean(float(prior[idx[0]]), prior_weight, tau)
            for i in idx:
                out[i] = mean.centre(float(scores[i]))
    return out


def _restrict(streams: Sequence[np.ndarray], keep: np.ndarray) -> list[np.ndarray]:
    """The streams over the kept frames only, as indices into the kept subset."""
    local = np.cumsum(keep) - 1
    return [local[idx[keep[idx]]] for idx in streams if keep[idx].any()]


def _held_out_with_priors(x: np.ndarray, y: np.ndarray, groups: np.ndarray,
                          lambdas: Sequence[float]) -> tuple[dict, dict]:
    """Per lambda: each frame's ridge score from a fit without its group, and that fit's mean training score (the
    fit's offset, the mean of the training frames' +-1 targets: the same for every lambda)."""
    target = np.where(y, 1.0, -1.0)
    prior = np.zeros(len(y))
    for g in group_names(groups):
        held = _held(groups, g)
        prior[held] = target[~held].mean()
    return held_out_scores(x, y, groups, lambdas), {lam: prior for lam in lambdas}


def criterion(scores: np.ndarray, y: np.ndarray, groups: np.ndarray) -> float:
    """What a choice is judged by: the mean of the per-group mean AUROC and the pooled AUROC."""
    return 0.5 * (group_mean_auroc(scores, y, groups) + float(auroc(scores, y)))


def nested_centred_holdout(x: np.ndarray, y: np.ndarray, groups: np.ndarray, streams: Sequence[np.ndarray],
                           lambdas: Sequence[float] = LAMBDAS,
                           weights: Sequence[float | None] = PRIOR_WEIGHTS) -> tuple[np.ndarray, dict]:
    """Each frame's centred score from a head fitted without its group, the ridge strength and the prior's weight
    chosen by leave-one-group-out on the other groups only; and {group: (lambda, prior weight)} chosen."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=bool)
    out = np.zeros(len(y))
    chosen: dict[str, tuple[float, float | None]] = {}
    for g in group_names(groups):
        held = _held(groups, g)
        rest = ~held
        inner_streams = _restrict(streams, rest)
        scores, priors = _held_out_with_priors(x[rest], y[rest], groups[rest], lambdas)
        options = [(lam, w) for lam in lambdas for w in weights]
        lam, w = max(options, key=lambda o: (criterion(centred(scores[o[0]], inner_streams, priors[o[0]], o[1]),
                                                       y[rest], groups[rest]), o[0], -(o[1] or 0.0)))
        mean, scale, [(wv, offset)] = _ridge_all(x[rest], y[rest], [lam])
        raw = np.zeros(len(y))
        raw[held] = ((x[held] - mean) / scale) @ wv + offset
        held_streams = [idx[held[idx]] for idx in streams if held[idx].any()]
        out[held] = centred(raw, held_streams, np.full(len(y), offset), w)[held]
        chosen[g] = (lam, w)
    return out, chosen


def held_out_centred(features: np.ndarray, frames: Sequence[LabelledFrame], seed: int = ORDER_SEED) -> dict:
    """Per-group AUROC of the fish head centred by each dive's running mean, every choice nested (what
    ``merlion eval auroc --data --holdout`` prints as "dive-centred")."""
    y = np.array([f.fish for f in frames])
    groups = np.array([f.group for f in frames])
    scores, chosen = nested_centred_holdout(np.asarray(features, np.float64), y, groups, stream_order(frames, seed))
    by_group = per_group(scores, frames)
    return {"method": f"fish head minus the dive's running mean (tau {TAU:g} frames), ridge strength and prior "
                      f"weight chosen without each group (DeepFish order seed {seed})",
            "by_group": by_group, "deepfish_habitats": spread(by_group, DEEPFISH),
            "deepfish_pooled": float(auroc(scores[_deepfish(frames)], y[_deepfish(frames)])),
            "chosen": {g: {"lambda": lam, "prior_weight": w} for g, (lam, w) in chosen.items()}}


def _deepfish(frames: Sequence[LabelledFrame]) -> np.ndarray:
    return np.array([f.source.startswith(DEEPFISH) for f in frames])
