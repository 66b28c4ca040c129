"""The tau_ss gate on frames as captured, for every topic followed (enhance.mode selective on the vehicle).

With selective enhancement the inference thread only scores frames and hands those that pass to the enhancer's
worker (companion/live/enhance_worker.py). With several topics (issue 13 item 4) every topic scores the one
embedding with its own queries and threshold: a frame is a candidate when any topic passes, and it carries the
names of the topics it passed for, so that after enhancement it may enter only those topics' summaries (the
method's ss_t > tau_ss, then ss_e > tau_ses, per topic, as ``Pipeline`` does offline). Like the pipeline, the
gate owns the dive's running mean of the frames it scores (``dive``), fed once per frame and read by every topic.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.vision.dive_mean import DiveFrames, DiveWindow
from companion.vision.encoders.base import Encoder
from companion.vision.presampler import PreSampler
from companion.vision.topics import TopicSpec, check_names, follow, score_matrix


class RawGate:
    """One pre-sampler per topic, in the pipeline's topic order; ``tau_ss`` is the default for new topics."""

    def __init__(self, encoder: Encoder, specs: Sequence[TopicSpec], tau_ss: float) -> None:
        self.encoder = encoder
        self.default_tau = tau_ss
        self.dive = DiveWindow()
        """The dive as captured (the frames this gate scores), one for every topic."""
        self.presamplers: dict[str, PreSampler] = {}
        self.set_topics(specs)

    @property
    def names(self) -> list[str]:
        return list(self.presamplers)

    def set_topics(self, specs: Sequence[TopicSpec]) -> None:
        """Follow these topics: a kept name keeps its pre-sampler (and marks) under its new queries."""
        check_names([s.name for s in specs])
        old = self.presamplers
        self.presamplers = {spec.name: follow(spec, old.get(spec.name), self.encoder, self.default_tau, self.dive)
                            for spec in specs}

    @property
    def tau_ss(self) -> float:
        """The default threshold (MERL_TAU_SS)."""
        return self.default_tau

    @tau_ss.setter
    def tau_ss(self, value: float) -> None:
        """Every topic's threshold, as MERL_TAU_SS sets it on the pipeline."""
        for presampler in self.presamplers.values():
            presampler.tau_ss = value
        self.default_tau = next(iter(self.presamplers.values())).tau_ss

    def tau_of(self, name: str) -> float:
        return self.presamplers[name].tau_ss if name in self.presamplers else self.default_tau

    def take(self, embeddings: np.ndarray) -> DiveFrames:
        """A batch of frames as captured, taken into the dive of raw frames (also while the enhancer is off and
        the frames go straight to the pipeline, which this gate then judges: ``OuterDive``), so that dive never
        misses a frame."""
        return self.dive.take(self.encoder.sampler_features(embeddings), scene=self.encoder.scene_input(embeddings),
                              embeddings=embeddings)

    def scorer(self, topic: str) -> PreSampler:
        """The topic's pre-sampler in the dive of raw frames, with its marks: it scores the enhanced copies and,
        while the enhancer is off, the frames the pipeline gets (``OuterDive``)."""
        return self.presamplers[topic]

    def score(self, embeddings: np.ndarray) -> tuple[np.ndarray, list[dict[str, float]], DiveFrames]:
        """Each frame's best ss_t over the topics, the topics it passed for with its ss_t for each (empty: none),
        and the frames as the dive saw them, by which their enhanced copies are judged (``DiveFrames.copies``)."""
        frames = self.take(embeddings)
        scores, passed = score_matrix(list(self.presamplers.values()), embeddings, frames)
        names = self.names
        return (scores.max(axis=1),
                [{names[t]: float(scores[i, t]) for t in np.flatnonzero(row)} for i, row in enumerate(passed)], frames)
