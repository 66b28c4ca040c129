"""How much the operator's marks help: AUROC of the rest of a labelled set with and without N + N marks.

The first N positive and the first N negative items (in name order, or the dive's frame order, as an operator would
meet them on a dive) become the marks; every other item is scored twice, by the query alone and by the query
combined with the marks (``companion.vision.feedback``), on the same encoder pass. Used by ``merlion eval
feedback`` and ``merlion eval auroc --marks``.

The items are streamed through the same ``MarkedPreSampler`` the live companion uses, one frame at a time in
order: the dive's running mean sees the frames up to the last mark, the marks are set there (centred by the dive's
mean at that moment, as a live upload is), and then the dive is streamed again from its start with the marks in
force, so every unmarked frame, also one met before the marks, is scored by a causal running mean.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.errors import MerlionError, UsageError
from companion.evaluation.roc import auroc
from companion.vision.encoders.base import Encoder
from companion.vision.feedback import CENTRED_WEIGHT, MarkedPreSampler, Marks
from companion.vision.presampler import PreSampler


@dataclass(frozen=True)
class FeedbackResult:
    marks: int
    scored: int
    positives: int
    auroc_query: float
    auroc_marked: float
    trust: float = 1.0
    """How far the marks were trusted (``companion.vision.feedback``): their weight's share of n / (n + 2)."""
    centred_trust: float = 0.0
    """How far the dive-centred marks were trusted (their leave-one-out agreement)."""

    def as_dict(self) -> dict:
        return self.__dict__.copy()


def read_item_labels(path: str | Path) -> dict[str, bool]:
    """A CSV with a header: first column the image name (or 0-based ``frame_index``), then a ``*_present``
    column (else ``label`` / ``positive``), non-zero = positive. Keys are file names or frame numbers as text."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"--labels {p}: no such file")
    with p.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        fields = reader.fieldnames or []
        column = next((f for f in fields if f.endswith("_present")), None) or next(
            (f for f in fields if f in ("label", "positive")), None)
        if not fields or column is None:
            raise MerlionError(f"{p}: needs a header with an image column and a *_present (or label) column")
        out: dict[str, bool] = {}
        for line, row in enumerate(reader, start=2):
            item = (row[fields[0]] or "").strip()
            if item in out:  # a second row would silently overrule the first
                raise MerlionError(f"{p}: line {line}: {fields[0]} {item!r} is listed twice")
            try:
                out[item] = float(row[column] or 0) != 0
            except (TypeError, ValueError):
                raise MerlionError(f"{p}: line {line}: {column}={row[column]!r} is not a number") from None
    return out


def split_marks(positive: Sequence[bool], n: int) -> tuple[list[int], list[int], list[int]]:
    """Indices of the first n positives, the first n negatives, and the rest (the items to score)."""
    pos = [i for i, y in enumerate(positive) if y][:n]
    neg = [i for i, y in enumerate(positive) if not y][:n]
    if len(pos) < n or len(neg) < n:
        raise MerlionError(f"--marks {n}: needs {n} positive and {n} negative items, "
                           f"have {sum(positive)} and {len(positive) - sum(positive)}")
    taken = set(pos) | set(neg)
    return pos, neg, [i for i in range(len(positive)) if i not in taken]


def evaluate(encoder: Encoder, presampler: PreSampler, embeddings: np.ndarray, positive: Sequence[bool],
             n: int, centred_weight: float = CENTRED_WEIGHT) -> FeedbackResult:
    """AUROC of the unmarked items by the query alone and with the first n + n items (in the given order, the
    dive's) as marks; ``presampler`` is left as it was (a fresh dive is streamed). ``centred_weight``: the
    dive-centred marks' weight (the product's unless a nested choice tries others)."""
    y = np.asarray(positive, dtype=bool)
    pos, neg, rest = split_marks(list(y), n)
    if not y[rest].any() or y[rest].all():
        raise MerlionError(f"--marks {n}: the items left to score hold only one class")
    dive = PreSampler(encoder, presampler.positive, presampler.negatives, presampler.tau_ss)
    alone = PreSampler(encoder, presampler.positive, presampler.negatives, presampler.tau_ss)
    own = alone.scores(embeddings)  # the query alone, the dive streamed as the companion scores it
    marked = MarkedPreSampler(dive, Marks(np.zeros((0, 1)), np.zeros((0, 1))))
    marked.centred_weight = centred_weight
    last = max(pos[-1], neg[-1]) if n else -1
    for i in range(last + 1):  # the dive up to the last mark, as the companion met it
        marked.scores(embeddings[i:i + 1])
    feats = encoder.object_features(embeddings, presampler.text_embeddings)
    pooled = encoder.sampler_features(embeddings)
    marked.set_marks(Marks.from_features(feats[pos], feats[neg], own[pos], own[neg], objects=True,
                                         like_pooled=pooled[pos], unlike_pooled=pooled[neg]))
    marked.new_dive()
    combined = np.concatenate([marked.scores(embeddings[i:i + 1]) for i in range(len(y))])
    return FeedbackResult(n, len(rest), int(y[rest].sum()), auroc(own[rest], y[rest]), auroc(combined[rest], y[rest]),
                          marked.trust, marked.centred_trust)
