"""Semantic pre-sampling: keep only the frames whose score for the positive query passes ``tau_ss``.

``ss_t`` is REFERENCE.md section 1 step 1: the share of the positive query in ``softmax(100 x cos)`` over the
positive and the negatives. The encoder computes it (``Encoder.semantic_scores``) because encoders without a
text tower define the share through concept masses; this module owns the queries, their embeddings (computed
once) and the threshold, all of which can change while running.

A positive with no negative would make the softmax share 1 for every frame, so a generic negative,
``GENERIC_NEGATIVE`` ("an underwater image"), is used: the positive then has to describe the frame better than
a plain description of any underwater scene. An encoder that cannot embed that phrase (the packaged ImageNet
encoder answers only marine concepts) scores the positive alone, which it defines as the positive concept's
probability mass.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from companion.config import as_fraction
from companion.errors import MerlionError, UsageError
from companion.vision.dive_mean import DiveFrames, DiveWindow, QueryWindow
from companion.vision.encoders.base import Encoder

log = logging.getLogger(__name__)

GENERIC_NEGATIVE = "an underwater image"


class PreSampler:
    """Scores image embeddings against the queries and says which frames pass ``tau_ss`` (strictly)."""

    def __init__(self, encoder: Encoder, positive: str, negatives: Sequence[str] = (), tau_ss: float = 0.5,
                 dive: DiveWindow | None = None) -> None:
        self.encoder = encoder
        self.tau_ss = tau_ss
        self.dive = DiveWindow() if dive is None else dive
        """The dive so far (running mean of the scored frames' features): what the operator's marks need. Shared
        with the other topics when what runs them all gives it (``dive``), else this pre-sampler's own."""
        self.recent_queries = QueryWindow()
        """This topic's query log-odds over the dive's recent frames (the marks' scale)."""
        self.set_queries(positive, negatives)

    def new_dive(self) -> None:
        """Forget the frames scored so far: the next frame starts a new dive's running mean, this pre-sampler's
        own (it no longer reads a dive it shared)."""
        self.dive = DiveWindow()
        self.recent_queries = QueryWindow()

    @property
    def tau_ss(self) -> float:
        return self._tau

    @tau_ss.setter
    def tau_ss(self, value: float) -> None:
        """A fraction in [0, 1); a value above 1 is read as a percentage (40 -> 0.4); 0: no semantic gate."""
        try:
            self._tau = as_fraction(float(value), allow_zero=True)
        except ValueError as err:
            raise UsageError(f"tau_ss: {err}") from None

    def set_queries(self, positive: str, negatives: Sequence[str] = ()) -> None:
        """Embed the queries once; with no negative, the generic one (see the module docstring)."""
        positive = positive.strip()
        negatives = [n.strip() for n in negatives if n.strip()]
        if not positive:
            raise UsageError("query: the positive query is empty")
        if negatives:
            texts = [positive, *negatives]
            embeddings = self.encoder.encode_texts(texts)
        else:
            try:
                texts = [positive, GENERIC_NEGATIVE]
                embeddings = self.encoder.encode_texts(texts)
            except MerlionError:
                texts = [positive]
                embeddings = self.encoder.encode_texts(texts)
                log.info("no negative query: %s scores the positive alone", self.encoder.name)
        self.positive = positive
        self.negatives = texts[1:]
        self.text_embeddings = np.asarray(embeddings)

    @property
    def queries(self) -> list[str]:
        """The texts actually scored: the positive first."""
        return [self.positive, *self.negatives]

    def query_scores(self, image_embeddings: np.ndarray) -> np.ndarray:
        """(N,) float32 ss_t in (0, 1) for a batch of image embeddings, without taking them into the dive."""
        if len(image_embeddings) == 0:
            return np.zeros(0, dtype=np.float32)
        return np.asarray(self.encoder.semantic_scores(image_embeddings, self.text_embeddings), dtype=np.float32)

    def scores(self, image_embeddings: np.ndarray, *, join: bool = True,
               pooled: np.ndarray | None = None) -> np.ndarray:
        """(N,) float32 ss_t in (0, 1) for a batch of frames of the dive, in order, by a pre-sampler used alone:
        each frame joins ``dive`` unless ``join`` is False (a frame scored again, e.g. its enhanced copy).
        ``pooled``: the batch's ``encoder.sampler_features``, when the caller has them already.

        Several topics over one encoder pass share one dive, fed once per frame: their runner calls
        ``dive.take`` and then ``scores_in_dive`` of each topic (``companion.vision.topics.score_matrix``)."""
        if len(image_embeddings) == 0:
            return self.query_scores(image_embeddings)
        if pooled is None:
            pooled = self.encoder.sampler_features(image_embeddings)
        return self.scores_in_dive(image_embeddings,
                                   self.dive.take(pooled, join, self.encoder.scene_input(image_embeddings)))

    def scores_in_dive(self, image_embeddings: np.ndarray, frames: DiveFrames) -> np.ndarray:
        """(N,) float32 ss_t of a batch that ``dive`` has already seen (``frames``: what ``dive.take`` gave); with
        the frames' scene residuals, a head that reads them answers (``Encoder.with_scene``)."""
        if frames.scene is not None and len(image_embeddings):
            image_embeddings = self.encoder.with_scene(image_embeddings, frames.scene)
        s = self.query_scores(image_embeddings)
        if len(s) and frames.joined:
            self.recent_queries.add(s)
        return s

    def passes(self, scores: np.ndarray, tau: float | None = None) -> np.ndarray:
        """Boolean mask: ``score > tau`` (``tau_ss`` unless another threshold, e.g. tau_ses, is given).

        A threshold of 0 is no gate at all: every frame passes, also one whose share underflowed to 0.0.
        """
        tau = self._tau if tau is None else tau
        if tau <= 0.0:
            return np.ones(len(scores), dtype=bool)
        return np.asarray(scores) > tau


def softmax_share(image_embeddings: np.ndarray, text_embeddings: np.ndarray, scale: float = 100.0) -> np.ndarray:
    """REFERENCE.md's ss_t for embedding encoders: softmax(scale x cos(v, q_j))[0], the positive query's share.

    L2-normalises both sides; the fixed scale 100 is the reference implementation's (not a learned logit scale).
    """
    v = np.asarray(image_embeddings, dtype=np.float64)
    q = np.asarray(text_embeddings, dtype=np.float64)
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    logits = scale * (v @ q.T)
    logits -= logits.max(axis=1, keepdims=True)
    e = np.exp(logits)
    return (e[:, 0] / e.sum(axis=1)).astype(np.float32)
