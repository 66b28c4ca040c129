"""The marks' effect per group: in each labelled group (a DeepFish habitat, a source), the first N positive and N
negative frames become the operator's marks and the rest are scored with and without them.

With ``held_out`` the learned heads that answer the query (the pooled one, and the scene one on each order's scene
residuals, with the pasted frames of the other groups when given) are retrained without the group first, so neither the query score nor the marks' effect comes from a
head that saw the group. Each group is streamed in its dive's
order (``dive_centring.stream_order``: videos in order, each DeepFish habitat in a seeded random order, since its
label file lists the fish frames first), once per seed.

The dive-centred marks' weight is chosen nested: for each reported group, among ``WEIGHTS``, on the other groups
only (``choose_weight``), keeping the groups it is chosen on within half the loss the marks are allowed and ranking
the weights that do so by the median dive's gain. The same rule on every group gives the product's
``CENTRED_WEIGHT``. Used by ``merlion eval auroc --data --marks N``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from companion.errors import MerlionError
from companion.evaluation.dive_centring import ORDER_SEED, stream_order
from companion.evaluation.feedback_eval import evaluate
from companion.evaluation.head_training import Extra, extra_without, fit, with_extra
from companion.evaluation.holdout import groups_of, over_orders
from companion.evaluation.pasted_fish import PastedFish
from companion.evaluation.scene_holdout import pasted_rows, scene_features
from companion.evaluation.sources import LabelledFrame
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.encoders.learned_head import LinearHead
from companion.vision.presampler import PreSampler


def _head_without(head: LinearHead, features: np.ndarray, y: np.ndarray, keep: np.ndarray,
                  extra: Extra | None = None) -> LinearHead:
    """``head`` refitted at its own strength and scale floor on the ``keep`` rows (and ``extra``, already without
    the group)."""
    keep = keep & np.isfinite(features).all(axis=1)  # a scene head: not the dives' first frames
    lam = float(head.trained_on.get("lambda", 1e4))
    floor = float(head.trained_on.get("scale_floor", 0.0))
    refit = fit(*with_extra(features[keep], y[keep], extra), lam, calibrate=int(keep.sum()), floor=floor)
    return LinearHead(head.concept, head.classes, head.backbone, head.colour, refit.w, refit.b,
                      {"lambda": lam, "scale_floor": floor, "held_out": True}, head.input)


WEIGHTS = (1.0, 2.0, 3.0, 4.0, 6.0)
"""Candidate weights of the dive-centred marks (``companion.vision.feedback.CENTRED_WEIGHT``)."""
MAX_LOSS = 0.02
"""The most AUROC the marks may cost a dive against the query alone (the bound they are held to)."""
SEEN_LOSS = MAX_LOSS / 2
"""A weight that costs any group it is chosen on more than this, in any order, is not a candidate: half the
bound, since the group held out is not seen by its own choice and may lose more than any seen (3 + 3 marks,
orders 0-19: the worst held-out loss was 2 to 4 times the worst of the others at the same weight)."""
TOLERANCE = 0.005
"""Weights whose median gain is within this of the best count as equal; the lightest of them is taken."""


def choose_weight(gains: dict[float, dict[int, dict[str, float]]], without: str | None = None) -> float:
    """The weight to use, from ``gains[weight][order][group]`` on the groups other than ``without``: the lightest
    whose median gain over the (order, group) dives is within ``TOLERANCE`` of the best among those that cost no
    group more than ``SEEN_LOSS`` in any order (each order is a dive of its own: a loss averaged away over orders
    is still a dive made worse); the lightest weight when none qualifies.

    The median, not the mean: the marks' gain is nearly all in the few groups the query fails on (7393: +0.31 at
    weight 1, +0.51 at 2), so by the mean one group's gain buys a heavier weight that gains the rest little and
    risks them; a heavier weight must help most dives (on the shared data none does, so the lightest weight that
    passes the loss check is taken). By the mean, the weight chosen without 9870 on orders 20-39 was 2, and it cost 9870 0.026 and
    0.036 in two of them (docs/encoders.md, "A median dive for the marks' weight")."""
    seen = {w: [v for order in gains[w].values() for g, v in order.items() if g != without] for w in sorted(gains)}
    median = {w: float(np.median(v)) for w, v in seen.items() if v and min(v) >= -SEEN_LOSS}  # the safe ones
    if not median:
        return min(gains)
    best = max(median.values())
    return next(w for w, m in median.items() if m >= best - TOLERANCE)


def _summary(rows: dict) -> dict:
    gains = [r["gain"] for r in rows.values()]
    return {"groups": rows,
            "mean_gain": float(np.mean(gains)) if gains else None, "worst_gain": float(min(gains)) if gains else None,
            "mean_query": float(np.mean([r["auroc_query"] for r in rows.values()])) if rows else None,
            "mean_marked": float(np.mean([r["auroc_marked"] for r in rows.values()])) if rows else None}


def marks_by_group(encoder: ImageNetEncoder | object, presampler: PreSampler, embeddings: np.ndarray,
                   frames: Sequence[LabelledFrame], n: int, *, held_out: bool = True,
                   seeds: Sequence[int] = (ORDER_SEED,), weights: Sequence[float] = WEIGHTS,
                   pasted: PastedFish | None = None, progress: Callable[[str], None] = lambda _: None) -> dict:
    """{"groups": {group: {auroc_query, auroc_marked, gain, trust, centred_trust, weight}}, "mean_gain",
    "worst_gain", ...} for the first seed's order, the same per seed under "orders", "weight": the rule
    applied on every group (each group's weight is chosen without it), and "by_weight": each candidate weight's
    gain per order and group. Groups without n + n frames and something
    left of each class are skipped (listed under "skipped")."""
    y = np.array([f.fish for f in frames])
    in_group = {g: np.array([g in f.group.split("+") for f in frames]) for g in groups_of(frames)}
    head = encoder.head_of(presampler.text_embeddings) if hasattr(encoder, "head_of") else None
    features = encoder.sampler_features(embeddings).astype(np.float64)
    shipped = list(getattr(encoder, "heads", []))
    scene_head = encoder.scene_head_of(presampler.text_embeddings) if hasattr(encoder, "scene_head_of") else None
    inputs = encoder.scene_of(embeddings) if scene_head is not None else None
    scene = {seed: scene_features(inputs, frames, seed) for seed in seeds} if inputs is not None else {}
    extra = {seed: pasted_rows(inputs, frames, pasted, seed) for seed in seeds} if inputs is not None else {}
    orders = {seed: np.concatenate(stream_order(frames, seed)) for seed in seeds}
    tried: dict[int, dict[float, dict]] = {seed: {w: {} for w in weights} for seed in seeds}
    skipped = []
    try:
        for k, (g, mask) in enumerate(in_group.items(), 1):
            progress(f"group {g} ({k} of {len(in_group)})")
            if min(y[mask].sum(), (~y[mask]).sum()) < n + 1:
                skipped.append(g)
                continue
            if held_out and head is not None:
                encoder.heads = [_head_without(head, features, y, ~mask)]
            try:
                for seed, order in orders.items():
                    if held_out and scene_head is not None:  # the scene head too, retrained without the group
                        encoder.heads = [encoder.heads[0], _head_without(scene_head, scene[seed], y, ~mask,
                                                                         extra_without(extra[seed], g))]
                    idx = order[mask[order]]  # the group's frames in its dive's order
                    for w in weights:
                        r = evaluate(encoder, presampler, embeddings[idx], y[idx], n, w)
                        tried[seed][w][g] = {"auroc_query": r.auroc_query, "auroc_marked": r.auroc_marked,
                                             "gain": r.auroc_marked - r.auroc_query, "trust": r.trust,
                                             "centred_trust": r.centred_trust, "weight": w}
            except MerlionError:
                skipped.append(g)
    finally:
        if hasattr(encoder, "heads"):
            encoder.heads = shipped
    reported = [g for g in in_group if g not in skipped]
    gains = {w: {s: {g: tried[s][w][g]["gain"] for g in reported} for s in seeds} for w in weights}
    chosen = {g: choose_weight(gains, without=g) for g in reported}
    rows = {seed: {g: tried[seed][chosen[g]][g] for g in reported} for seed in seeds}
    first = seeds[0]
    by_weight = {str(w): {str(s): order for s, order in per.items()} for w, per in gains.items()}  # what it chose from
    return {"by_weight": by_weight, "marks": n, "held_out": bool(held_out and head is not None), "skipped": skipped, "seed": first,
            "weight": choose_weight(gains) if reported else None, **_summary(rows[first]),
            "orders": (per_order := {str(seed): _summary(rows[seed]) for seed in seeds}),
            "over_orders": over_orders(per_order, {k: k for k in ("mean_query", "mean_marked", "mean_gain",
                                                                  "worst_gain")}) if reported else {}}
