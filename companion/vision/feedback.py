"""The operator's marked examples ("more like this" / "not this") combined with the text or concept score.

No text query knows what this operator wants on this dive, and no vocabulary covers every target; a few marked
frames do. Marks teach the object, not the scene: each frame is represented by the features of its most
query-like part (``Encoder.object_features``: the packaged encoder's region where the query is strongest; CLIP's
whole-frame embedding), so marks from the first minutes of a dive do not learn its sea bed. A nearest-centroid
rule scores every frame: ``d = (f - mid) . w / (|w|^2 / 2)``
with ``w = like - unlike`` (the two prototypes), so ``d`` is +1 at the "like" prototype, -1 at the "unlike"
one and 0 half way, whatever the feature scale. With marks on one side only, the other prototype is the running
mean of the frames scored so far ("not this" = "what this dive usually looks like").

The combined score is ``(1 - w) * text + w * sigmoid(GAIN * d)`` with ``w = trust * n / (n + 2)`` for n marks:
one mark of each kind weighs as much as the query, five of each 0.83, as far as the marks are trusted. Trust
comes from the marks checked against each other, leave-one-out: each mark is scored by the prototypes of the
other marks, combined with its own query score at a few trial weights, and the marks are trusted only at the
largest trial weight that ranks the marked frames better than the query alone does (0 when none does: marks from
a dive's first minutes that only repeat what the query already says, or that contradict each other, then weigh
nothing). Without the marks' query scores, trust is the marks' leave-one-out agreement, ``max(0, 2 * accuracy -
1)``. The score stays in (0, 1), so tau_ss keeps its meaning. The same ``MarkedPreSampler`` serves ``merlion score``, ``merlion summarize`` and the live companion.

Dive-centred marks (``CentredMarks``): a frame's pooled features minus its dive's running mean
(``companion.vision.dive_mean``, one per dive, read by every topic's pre-sampler) drop the dive's water and sea bed.
With two or more marks of each kind, the marks' centred features give a direction, ``like mean - unlike mean``;
every frame's centred features are projected on it and the result, scaled to the query's spread over the dive's
recent frames, is added to the score's log-odds with weight ``CENTRED_WEIGHT x trust x doubt``. Trust is the
marks' leave-one-out agreement in the centred space (each mark checked against the direction of the others), 0
when they do not agree, so marks that contradict each other change nothing. Doubt is how far the query alone
fails to sort the marks (``1 - max(0, 2 * AUROC - 1)`` over their (like, unlike) pairs: 1 at chance or worse):
marks the query already sorts right add nothing it does not know, and a direction learnt from three frames of each kind at the start of a dive lowered the rest of some
well-ranked habitats by up to 0.12 AUROC; marks that the query ranks backwards (a habitat where it fails) weigh
fully. Without doubt, 3 + 3 marks cost some held-out habitat more than 0.02 in 12 of 20 frame orders; with it,
in 3, and in none of 40 since the weight keeps a margin (docs/encoders.md, "Marks weighed by the query's doubt",
"A margin for the group the choice cannot see"). Where they can be checked (two or more of
each kind, given while the dive runs: the live companion's marks) they replace the nearest-centroid rule above
(which still serves marks given before the dive, ``--like``/``--unlike`` of ``merlion score``/``summarize``), which cost up to 0.2 AUROC on a
held-out DeepFish habitat where the centred marks were not trusted (docs/vision.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.errors import UsageError
from companion.sources.folder import collect_images
from companion.vision.dive_mean import DiveFrames, DiveWindow, QueryWindow, logit
from companion.vision.encoders.base import Encoder
from companion.vision.presampler import PreSampler

TRIAL_TRUST = (0.25, 0.5, 0.75, 1.0)
"""Fractions of ``mark_weight`` tried, leave-one-out on the marks, to decide how far they are trusted."""
GAIN = 3.0
"""Slope of the example score at the mid point: d = +1 (the like prototype) maps to sigmoid(3) = 0.95."""
CENTRED_WEIGHT = 1.0
"""The dive-centred marks' score, in units of the query's spread, times their trust and doubt (module docstring):
chosen among 1, 2, 3, 4 and 6 by ``companion.evaluation.group_feedback.choose_weight`` on the shared data's 13
groups (3 + 3 marks, ten frame orders: ``merlion eval auroc --data ../shared/data --holdout --marks 3 --orders
10``; three orders allow 3); the evaluation chooses it again without each reported group. It was 3 while the
query was the pooled fish head, 4 with the first scene head, 3 again since the scene head also learns from
pasted fish (2026-11-27), 2 since the marks weigh by the query's doubt and no order may cost a group more
than 0.02 (2026-11-28), and 1 since a weight must keep the groups it is chosen on within half that (0.01; twenty
orders: at 2 one held-out habitat lost 0.037 in one of them, at 1 none lost more than 0.015). Since the rule ranks
weights by the median dive's gain rather than the mean (2026-11-29) it still gives 1, in each of three sets of
twenty orders."""


def _normalised(features: np.ndarray) -> np.ndarray:
    f = np.asarray(features, dtype=np.float64)
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-12)


@dataclass
class Marks:
    """Object features of the marked frames, L2-normalised, one row per mark, and their query scores (if known)."""

    like: np.ndarray
    unlike: np.ndarray
    like_query: np.ndarray | None = None
    unlike_query: np.ndarray | None = None
    objects: bool = False
    """True: rows are ``Encoder.object_features`` (frames are then scored by theirs); False: sampler features."""
    like_pooled: np.ndarray | None = None
    unlike_pooled: np.ndarray | None = None
    """The marked frames' pooled (sampler) features as the encoder gives them: what ``CentredMarks`` centres."""

    def __len__(self) -> int:
        return len(self.like) + len(self.unlike)

    @classmethod
    def from_features(cls, like: np.ndarray, unlike: np.ndarray, like_query: np.ndarray | None = None,
                      unlike_query: np.ndarray | None = None, *, objects: bool = False,
                      like_pooled: np.ndarray | None = None, unlike_pooled: np.ndarray | None = None) -> Marks:
        dim = like.shape[-1] if len(like) else unlike.shape[-1]
        pooled = None if like_pooled is None or unlike_pooled is None else (
            np.asarray(like_pooled, np.float64), np.asarray(unlike_pooled, np.float64))
        return cls(_normalised(np.reshape(like, (len(like), dim))), _normalised(np.reshape(unlike, (len(unlike), dim))),
                   None if like_query is None else np.asarray(like_query, np.float64),
                   None if unlike_query is None else np.asarray(unlike_query, np.float64), objects,
                   *(pooled or (None, None)))

    @classmethod
    def from_images(cls, encoder: Encoder, like: Sequence[np.ndarray], unlike: Sequence[np.ndarray],
                    text_embeddings: np.ndarray | None = None, scores: tuple[Sequence[float], Sequence[float]]
                    | None = None) -> Marks:
        """Marks from images: with the queries (``text_embeddings``), object features and query scores. ``scores``
        (like, unlike): the query scores the frames had in their dive, which the dive-centred marks' doubt is
        measured with; without them each image is scored on its own."""
        def feats(images: Sequence[np.ndarray], known: Sequence[float] | None
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
            if not images:
                return np.zeros((0, 1)), None if text_embeddings is None else np.zeros(0), None
            emb = encoder.encode_images(list(images))
            pooled = encoder.sampler_features(emb)
            if text_embeddings is None:
                return pooled, None, pooled
            query = (encoder.semantic_scores(emb, text_embeddings) if known is None
                     else np.asarray(known, np.float64))  # the frames' own scores are not asked for again
            return encoder.object_features(emb, text_embeddings), query, pooled

        known = scores if scores is not None else (None, None)
        (like_f, like_q, like_p), (unlike_f, unlike_q, unlike_p) = feats(like, known[0]), feats(unlike, known[1])
        return cls.from_features(like_f, unlike_f, like_q, unlike_q, objects=text_embeddings is not None,
                                 like_pooled=like_p, unlike_pooled=unlike_p)

    def _loo_example_scores(self) -> np.ndarray | None:
        """Each mark's example score from the other marks (like rows first); None when a side has one mark."""
        if len(self.like) < 2 or len(self.unlike) < 2:
            return None
        out = []
        for side in ("like", "unlike"):
            rows = getattr(self, side)
            for i in range(len(rows)):
                rest = np.delete(rows, i, axis=0)
                others = Marks(rest, self.unlike) if side == "like" else Marks(self.like, rest)  # rows as given
                out.append(ExampleScorer(others).scores(rows[i:i + 1])[0])
        return np.array(out)

    def trust(self) -> float:
        """How far the marks are trusted, in [0, 1] (module docstring)."""
        agreement = self.agreement()
        loo = self._loo_example_scores()
        if loo is None or self.like_query is None or self.unlike_query is None or agreement == 0.0:
            return agreement
        query = np.concatenate([self.like_query, self.unlike_query])
        positive = np.arange(len(query)) < len(self.like)
        weight = mark_weight(len(self))
        best, trusted = _pair_auroc(query, positive), 0.0
        for t in TRIAL_TRUST:
            area = _pair_auroc((1.0 - t * weight) * query + t * weight * loo, positive)
            if area > best + 1e-9:
                best, trusted = area, t
        return trusted * agreement

    def agreement(self) -> float:
        """Leave-one-out agreement in [0, 1]: 1 when every checkable mark falls on its own side of the others'
        prototypes, 0 at chance or worse; 1 when no mark can be checked (one mark on a side, or one side)."""
        return loo_agreement(self.like, self.unlike)


def loo_agreement(like: np.ndarray, unlike: np.ndarray) -> float:
    """Each mark checked against the prototypes of the others (itself left out): ``max(0, 2 * right share - 1)``;
    1 when no mark can be checked."""
    right = checked = 0
    for side, other in ((like, unlike), (unlike, like)):
        if len(side) < 2 or not len(other):
            continue
        for i in range(len(side)):
            rest = np.delete(side, i, axis=0).mean(axis=0)
            centre = other.mean(axis=0)
            d = (side[i] - (rest + centre) / 2.0) @ (rest - centre)  # > 0: on its own side
            right += int(d > 0)
            checked += 1
    if not checked:
        return 1.0
    return max(0.0, 2.0 * right / checked - 1.0)


@dataclass
class CentredMarks:
    """The marks as differences from their dive: a direction in pooled-feature space and how far it is trusted."""

    direction: np.ndarray
    trust: float
    along: np.ndarray
    """The marks' own projections and query log-odds: context for the scale while the dive has few frames."""
    logits: np.ndarray
    doubt: float = 1.0
    """How far the query alone fails to sort the marks: ``1 - max(0, 2 * AUROC - 1)`` over their (like, unlike)
    pairs, 1 at chance or worse and without their query scores. The lift is scaled by it (module docstring)."""

    @classmethod
    def of(cls, marks: Marks, dive_mean: np.ndarray | None) -> CentredMarks | None:
        """None when the marks lack pooled features, a side has fewer than two marks (nothing to check), or no
        frame of the dive has been scored yet (marks given before the dive: nothing to centre them by)."""
        if marks.like_pooled is None or marks.unlike_pooled is None or dive_mean is None:
            return None
        if len(marks.like_pooled) < 2 or len(marks.unlike_pooled) < 2:
            return None
        like, unlike = marks.like_pooled - dive_mean, marks.unlike_pooled - dive_mean
        trust = loo_agreement(like, unlike)
        direction = like.mean(axis=0) - unlike.mean(axis=0)
        query = (np.zeros(0) if marks.like_query is None or marks.unlike_query is None
                 else logit(np.concatenate([marks.like_query, marks.unlike_query])))
        # the query's own agreement with the marks, as the marks' is measured: 0 at chance or worse
        sure = 0.0 if not len(query) else max(0.0, 2.0 * _pair_auroc(query, np.arange(len(query)) < len(like)) - 1.0)
        doubt = 1.0 - sure
        return cls(direction, trust, np.concatenate([like, unlike]) @ direction, query, doubt)

    def lift(self, centred: np.ndarray, dive: DiveWindow, queries: QueryWindow,
             weight: float = CENTRED_WEIGHT) -> np.ndarray:
        """What the marks add to each frame's log-odds: its centred features along the direction, less the recent
        frames' mean, in units of the query's spread (``queries``, the topic's own) over the recent frames."""
        recent, recent_q = dive.recent_features(), queries.values()
        along = np.concatenate([recent @ self.direction if len(recent) else np.zeros(0), self.along])
        spread_q = float(np.std(np.concatenate([recent_q, self.logits])))
        spread_m = float(np.std(along))
        if spread_m < 1e-12 or spread_q < 1e-12:
            return np.zeros(len(centred))
        return weight * self.doubt * self.trust * spread_q * (centred @ self.direction - along.mean()) / spread_m


@dataclass
class ExampleScorer:
    """Nearest-centroid score of frames against the marks, in (0, 1); 0.5 half way between the prototypes."""

    marks: Marks
    _seen_sum: np.ndarray | None = field(default=None, repr=False)
    _seen: int = 0

    def observe(self, features: np.ndarray) -> None:
        """Add frames to the running mean that stands in for a missing side."""
        f = _normalised(features)
        self._seen_sum = f.sum(axis=0) if self._seen_sum is None else self._seen_sum + f.sum(axis=0)
        self._seen += len(f)

    def _prototype(self, rows: np.ndarray) -> np.ndarray | None:
        if len(rows):
            return rows.mean(axis=0)
        if self._seen:
            return self._seen_sum / self._seen
        return None

    def scores(self, features: np.ndarray) -> np.ndarray:
        f = _normalised(features)
        like, unlike = self._prototype(self.marks.like), self._prototype(self.marks.unlike)
        if like is None or unlike is None:
            return np.full(len(f), 0.5)
        w = like - unlike
        half = float(w @ w) / 2.0
        if half < 1e-12:
            return np.full(len(f), 0.5)
        d = (f - (like + unlike) / 2.0) @ w / half
        return 1.0 / (1.0 + np.exp(-GAIN * d))


def _pair_auroc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Share of (positive, negative) pairs ranked right, ties half: the AUROC of a handful of marks."""
    diff = scores[positive][:, None] - scores[~positive][None, :]
    return float(((diff > 0) + 0.5 * (diff == 0)).mean())


def mark_weight(n: int) -> float:
    """Share of the combined score given to the marks: n / (n + 2)."""
    return n / (n + 2.0)


class MarkedPreSampler(PreSampler):
    """The pre-sampler with marks: same queries and tau_ss, score combined with the examples."""

    def __init__(self, base: PreSampler, marks: Marks) -> None:
        self.encoder = base.encoder
        self.tau_ss = base.tau_ss
        self.positive, self.negatives, self.text_embeddings = base.positive, base.negatives, base.text_embeddings
        self.dive = getattr(base, "dive", None) or DiveWindow()  # the dive so far, as the base saw it (shared)
        self.recent_queries = getattr(base, "recent_queries", None) or QueryWindow()
        self.centred_weight = CENTRED_WEIGHT
        self.set_marks(marks)

    def set_marks(self, marks: Marks) -> None:
        """New marks (or none); the dive-centred ones are centred by the dive's mean as it stands now."""
        self.examples = ExampleScorer(marks)
        self.objects = marks.objects
        self.centred = CentredMarks.of(marks, self.dive.mean)
        # the dive-centred marks, where they can be checked, replace the nearest-centroid rule (module docstring)
        self.trust = 0.0 if self.centred is not None else marks.trust()
        self.weight = self.trust * mark_weight(len(marks))

    @property
    def centred_trust(self) -> float:
        """Trust of the dive-centred marks (0 without them)."""
        return 0.0 if self.centred is None else self.centred.trust

    def text_scores(self, image_embeddings: np.ndarray) -> np.ndarray:
        return self.query_scores(image_embeddings)

    def scores_in_dive(self, image_embeddings: np.ndarray, frames: DiveFrames) -> np.ndarray:
        text = super().scores_in_dive(image_embeddings, frames)
        if len(image_embeddings) == 0:
            return text
        out = np.asarray(text, dtype=np.float64)
        if self.weight > 0.0:
            # the frames' own embeddings where the dive kept them: a copy is compared as its frame was
            own = image_embeddings if frames.embeddings is None else frames.embeddings
            feats = (self.encoder.object_features(own, self.text_embeddings) if self.objects else frames.pooled)
            if frames.joined:  # a copy (an enhanced frame) is no new frame of the dive
                self.examples.observe(feats)
            out = (1.0 - self.weight) * out + self.weight * self.examples.scores(feats)
        if self.centred_trust > 0.0:
            lift = self.centred.lift(frames.centred, self.dive, self.recent_queries, self.centred_weight)
            out = 1.0 / (1.0 + np.exp(-(logit(out) + lift)))
        return out.astype(np.float32)


def read_mark_images(paths: Sequence[str | Path], option: str) -> list[np.ndarray]:
    """Images named by --like/--unlike (a folder means every image in it); one-line errors name the file."""
    images = []
    for path in collect_images(paths):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise UsageError(f"{option} {path}: cannot decode as an image")
        images.append(img)
    return images


def with_marks(presampler: PreSampler, like: Sequence[np.ndarray], unlike: Sequence[np.ndarray]) -> PreSampler:
    """The pre-sampler to use given the marked images (unchanged when there are none)."""
    if not like and not unlike:
        return presampler
    return MarkedPreSampler(presampler, Marks.from_images(presampler.encoder, like, unlike,
                                                          presampler.text_embeddings))
