"""Several named topics followed at once: each with its own queries, threshold and summary of K frames.

An operator on a survey may want the fish, the corals and any debris, each as its own handful of frames. The
encoder is the expensive part and its image embedding does not depend on the query, so one encoder pass per
frame serves every topic: each topic scores the same embeddings with its own pre-sampler and offers the frames
that pass to its own informative sampler. With one topic (the default) this is exactly the paper's pipeline.

The dive's running mean of pooled features (``companion.vision.dive_mean``) does not depend on the query either:
what runs the topics (``Pipeline``, the live ``RawGate``) owns one ``DiveWindow``, gives it to every pre-sampler
it makes (``follow``) and feeds it once per batch before the topics score it (``score_matrix``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from companion.errors import UsageError
from companion.vision.below_threshold import BestBelow
from companion.vision.dive_mean import DiveFrames, DiveWindow
from companion.vision.encoders.base import Encoder
from companion.vision.events import SummaryFrame
from companion.vision.presampler import PreSampler
from companion.vision.sampler import InformativeSampler


@dataclass(frozen=True)
class TopicSpec:
    """What defines a topic: its name, queries and (optionally) its own tau_ss."""

    name: str
    positive: str
    negatives: tuple[str, ...] = ()
    tau_ss: float | None = None

    @classmethod
    def from_config(cls, topic) -> TopicSpec:
        return cls(topic.name, topic.positive, tuple(topic.negatives), topic.tau_ss)


@dataclass
class Topic:
    """One followed topic: its pre-sampler (queries, threshold, marks) and its own summary."""

    name: str
    presampler: PreSampler
    sampler: InformativeSampler
    held: dict[int, SummaryFrame] = field(default_factory=dict)
    """The summary frames by image index (the sampler's keys)."""
    below: BestBelow = field(default_factory=BestBelow)
    """Stand-ins while nothing passes: in the summary (``below.shown``) only while the sampler holds nothing."""
    pilot: list[int] = field(default_factory=list)
    """The pilot's own captures filed under this topic (in ``held`` too): outside the sampler, so nothing it
    trims for room ever takes one."""

    @property
    def keys(self) -> list[int]:
        """Image indices in the summary: the sampler's, then any stand-ins, then the pilot's captures."""
        return [*self.sampler.keys, *self.below.shown, *self.pilot]

    @property
    def summary(self) -> list[SummaryFrame]:
        """The frames held now, in the order they entered (stand-ins, then the pilot's captures, last)."""
        return ([self.held[key] for key in self.sampler.keys] + list(self.below.shown.values())
                + [self.held[key] for key in self.pilot])


def check_names(names: Sequence[str]) -> None:
    """Topics are told apart by name everywhere (captures, store, gallery): refuse none, or one used twice."""
    if not names:
        raise UsageError("queries: at least one topic is needed")
    twice = sorted({n for n in names if list(names).count(n) > 1})
    if twice:
        raise UsageError(f"queries: topic name {twice[0]!r} is used twice")


class OuterDive(Protocol):
    """A dive kept outside the pipeline that judges the frames handed to it: the live raw gate's dive of the frames
    as captured, with its topics' pre-samplers (their marks and recent scores), while the enhancer's pipeline sees
    only candidates, or the frames themselves while the enhancer is off."""

    def take(self, embeddings: np.ndarray) -> DiveFrames:
        """New frames, taken into the dive."""

    def scorer(self, topic: str) -> PreSampler:
        """The topic's pre-sampler in that dive (what scores; the pipeline's own keeps the threshold)."""


def score_matrix(presamplers: Sequence[PreSampler], embeddings: np.ndarray, frames: DiveFrames,
                 tau: float | None = None,
                 scorers: Sequence[PreSampler] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, T) scores and (N, T) pass masks (of each topic's tau_ss, or ``tau``) of every topic's pre-sampler on one
    batch of embeddings; ``frames``: the batch as the topics' shared dive took it in (``DiveWindow.take``).
    ``scorers``: per topic, another pre-sampler that scores (an ``OuterDive``'s), the threshold staying these'."""
    n = len(embeddings)
    scores = np.zeros((n, len(presamplers)), dtype=np.float32)
    passed = np.zeros((n, len(presamplers)), dtype=bool)
    for t, presampler in enumerate(presamplers):
        scores[:, t] = (presampler if scorers is None else scorers[t]).scores_in_dive(embeddings, frames)
        passed[:, t] = presampler.passes(scores[:, t], tau)
    return scores, passed


def follow(spec: TopicSpec, kept: PreSampler | None, encoder: Encoder, default_tau_ss: float,
           dive: DiveWindow) -> PreSampler:
    """The pre-sampler of ``spec`` from now on: a kept topic's own (its marks stay) under the new queries, or a
    new one at the shared threshold, reading the topics' ``dive``; the spec's own tau_ss, if it has one, wins."""
    if kept is None:
        kept = PreSampler(encoder, spec.positive, spec.negatives, default_tau_ss, dive)
    else:
        kept.set_queries(spec.positive, spec.negatives)
    if spec.tau_ss is not None:
        kept.tau_ss = spec.tau_ss
    return kept


def by_topic_name(frames: Sequence[SummaryFrame], names: Sequence[str],
                  untagged: str) -> tuple[dict[str, list[SummaryFrame]], list[SummaryFrame]]:
    """Stored frames sorted to the topics followed (a frame naming none: ``untagged``, and it is tagged so), and
    the frames of topics no longer followed."""
    by_topic: dict[str, list[SummaryFrame]] = {name: [] for name in names}
    dropped = []
    for frame in frames:
        name = frame.topic or untagged
        if name in by_topic:
            frame.topic = name
            by_topic[name].append(frame)
        else:
            dropped.append(frame)
    return by_topic, dropped
