"""SRUM, the paper's summary metric (REFERENCE.md section 1), exactly as Table I was computed.

A human frame earns credit from the best automatic frame that shares at least one label with it: half for the
label match (``alpha``, no decay), the other half for being close in time (full within ``tau`` seconds, then an
exponential decay with a one-second time constant). Frames are 1-based video frame numbers throughout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from companion.errors import MerlionError

Labels = Mapping[int, frozenset[str]]
"""1-based frame number -> set of labels (species); an empty set means nothing of interest."""

ALPHA = 0.5
TAU_S = 2.0
FPS = 30.0


@dataclass(frozen=True)
class SrumParams:
    """The three knobs of SRUM; the defaults are the paper's (``--weight 0.5 --threshold 2 --fps 30``)."""

    alpha: float = ALPHA
    tau_s: float = TAU_S
    fps: float = FPS

    def __post_init__(self) -> None:
        if not 0.0 <= self.alpha <= 1.0:
            raise MerlionError(f"alpha: must be in [0, 1], got {self.alpha}", exit_code=2)
        if not (math.isfinite(self.tau_s) and self.tau_s >= 0):  # "not >=" also refuses NaN
            raise MerlionError(f"tau: must be >= 0 seconds, got {self.tau_s}", exit_code=2)
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise MerlionError(f"fps: must be > 0, got {self.fps}", exit_code=2)


PAPER = SrumParams()
"""The settings Table I was computed with."""


def time_credit(a: int, h: int, params: SrumParams = PAPER) -> float:
    """1 within tau seconds, then exp(-(|a-h| - tau*fps)/fps): capped at 1 and continuous at the edge."""
    excess = (abs(a - h) - params.tau_s * params.fps) / params.fps
    return 1.0 if excess <= 0 else math.exp(-excess)


def _labels_of(labels: Labels, frame: int, what: str) -> frozenset[str]:
    try:
        return labels[frame]
    except KeyError:
        raise MerlionError(f"{what} frame {frame}: not in the label file (frames are 1-based)") from None


def pair_score(a: int, h: int, labels: Labels, params: SrumParams = PAPER) -> float:
    """Credit automatic frame ``a`` gives human frame ``h``: 0 unless they share a label (empty never matches)."""
    if not (_labels_of(labels, a, "summary") & _labels_of(labels, h, "human")):
        return 0.0
    return params.alpha + (1.0 - params.alpha) * time_credit(a, h, params)


def score(auto: Sequence[int], human: Sequence[int], labels: Labels, params: SrumParams = PAPER) -> float:
    """One human summary: mean over its frames (fixed denominator |H|) of the best automatic frame's credit.

    Many-to-one: one automatic frame may serve several human frames; order and duplicates do not matter.
    """
    if not human:
        raise MerlionError("human summary is empty")
    for a in auto:
        _labels_of(labels, a, "summary")
    total = 0.0
    for h in human:
        _labels_of(labels, h, "human")
        total += max((pair_score(a, h, labels, params) for a in auto), default=0.0)
    return total / len(human)


def srum(
    auto: Sequence[int], humans: Mapping[str, Sequence[int]], labels: Labels, params: SrumParams = PAPER
) -> float:
    """SRUM of an automatic summary: the arithmetic mean of its score against each human summary."""
    if not humans:
        raise MerlionError("no human summaries to score against")
    return sum(score(auto, h, labels, params) for h in humans.values()) / len(humans)


def human_score(humans: Mapping[str, Sequence[int]], labels: Labels, params: SrumParams = PAPER) -> float:
    """Leave-one-out: each human summary scored as if automatic against the others, then averaged."""
    if len(humans) < 2:
        raise MerlionError(f"the human score needs at least 2 human summaries, got {len(humans)}")
    values = []
    for hid, frames in humans.items():
        others = {k: v for k, v in humans.items() if k != hid}
        values.append(srum(frames, others, labels, params))
    return sum(values) / len(values)


def relative(value: float, human: float) -> float:
    """The paper's relative score, 100 x SRUM / Human (how close to people the summary comes)."""
    return 100.0 * value / human if human > 0 else float("nan")
