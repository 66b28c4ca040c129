"""Training a learned head (``companion.vision.encoders.learned_head``) on labelled underwater frames, honestly.

The head is a linear classifier on the packaged encoder's 1280 pooled features: ridge regression on standardised
features (closed form: one linear solve per regularisation strength on the smaller of the two Gram matrices),
then a two-parameter logistic fit (Platt) that turns its output into a probability. The regularisation strength
is chosen by leave-one-group-out on the training groups only, and ``nested_holdout`` reports each group with a
head whose every choice was made without it: the figures ``merlion eval train-head`` prints.

Groups: each DeepFish habitat is one group (one camera drop), the other sources are grouped as in
``companion.evaluation.sources`` (footage shared between sources is one group).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.evaluation.holdout import per_group, spread, subset_auroc
from companion.evaluation.roc import auroc
from companion.evaluation.sources import DEEPFISH, LabelledFrame
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.encoders.learned_head import LinearHead
from companion.vision.presampler import PreSampler
from companion.vision.scene_memory import SceneInput

LAMBDAS = (1e3, 1e4, 1e5)
"""Ridge strengths tried (on standardised features, summed squared error), chosen by leave-one-group-out."""


@dataclass(frozen=True)
class LinearFit:
    """``logit = features . w + b`` on raw (unstandardised) features."""

    w: np.ndarray
    b: float
    lam: float


def standard_scale(x: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Each feature's spread, held to at least ``floor`` x the median feature's spread: a feature almost constant
    in training (a residual channel that fired in a dozen rows) would otherwise be stretched a thousandfold
    wherever it does fire, and its weight alone would decide those frames."""
    std = x.std(axis=0)
    return np.maximum(std, floor * float(np.median(std))) + 1e-6


def _ridge_all(x: np.ndarray, y: np.ndarray, lambdas: Sequence[float],
               floor: float = 0.0) -> tuple[np.ndarray, np.ndarray, list]:
    """Standardisation (mean, scale; ``standard_scale``) and one ridge weight vector per lambda, by a linear solve
    each."""
    mean, scale = x.mean(axis=0), standard_scale(x, floor)
    z = (x - mean) / scale
    target = np.where(y, 1.0, -1.0)
    offset = target.mean()
    if len(z) <= z.shape[1]:
        # Fewer frames than features: w = z.T (z z.T + lam I)^-1 t, the SVD's weights from the frames' Gram
        # matrix (N x N). A linear solve per strength costs less than one eigendecomposition for up to a few
        # strengths (740 frames, one thread: 3 solves 0.04 s, eigh 0.09 s, the SVD 1.37 s).
        gram = z @ z.T
        eye = np.eye(len(z))
        ws = [z.T @ np.linalg.solve(gram + lam * eye, target - offset) for lam in lambdas]
        return mean, scale, [(w, offset) for w in ws]
    # More frames than features (the scene head with its pasted frames): the same weights from the features'
    # Gram matrix (D x D), one linear solve per strength.
    gram = z.T @ z
    zty = z.T @ (target - offset)
    eye = np.eye(z.shape[1])
    return mean, scale, [(np.linalg.solve(gram + lam * eye, zty), offset) for lam in lambdas]


def _platt(scores: np.ndarray, y: np.ndarray, iterations: int = 50) -> tuple[float, float]:
    """a, b of ``sigmoid(a * score + b)`` by Newton's method on the log-loss (with Platt's target smoothing)."""
    pos, neg = y.sum(), (~y).sum()
    t = np.where(y, (pos + 1) / (pos + 2), 1 / (neg + 2))
    a, b = 1.0, 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(a * scores + b)))
        g = np.array([((p - t) * scores).sum(), (p - t).sum()])
        r = p * (1 - p) + 1e-9
        h = np.array([[(r * scores * scores).sum(), (r * scores).sum()], [(r * scores).sum(), r.sum()]])
        step = np.linalg.solve(h + 1e-9 * np.eye(2), g)
        a, b = a - step[0], b - step[1]
        if np.abs(step).max() < 1e-9:
            break
    return float(a), float(b)


def fit(x: np.ndarray, y: np.ndarray, lam: float, calibrate: int | None = None, *, floor: float = 0.0) -> LinearFit:
    """Ridge on standardised features, calibrated by Platt on the training scores, folded into raw-feature w, b.
    ``calibrate``: Platt on the first rows only (the real frames, not the extra ones, whose share of fish would
    shift every probability); ``floor``: under the standardisation scale (``standard_scale``)."""
    y = np.asarray(y, dtype=bool)
    mean, scale, [(w, offset)] = _ridge_all(np.asarray(x, np.float64), y, [lam], floor)
    raw = ((x - mean) / scale) @ w + offset
    a, c = _platt(raw[:calibrate], y[:calibrate])
    w_raw = a * w / scale
    return LinearFit(w_raw, float(a * (offset - (mean / scale) @ w) + c), lam)


def _held(groups: np.ndarray, group: str) -> np.ndarray:
    """Frames of ``group``, including frames of a source shared with it (group names joined by "+")."""
    return np.array([group in g.split("+") for g in groups], dtype=bool)


def group_names(groups: np.ndarray) -> list[str]:
    return list(dict.fromkeys(n for g in groups for n in str(g).split("+")))


Extra = tuple[np.ndarray, np.ndarray, np.ndarray]
"""Training-only rows (features, labels, groups): fitted on, never scored, held out with every group they name."""


def with_extra(x: np.ndarray, y: np.ndarray, extra: Extra | None) -> tuple[np.ndarray, np.ndarray]:
    """The training rows, then the extra rows (real rows first: ``fit(..., calibrate=len(y))`` relies on it)."""
    if extra is None or not len(extra[0]):
        return x, y
    return np.concatenate([x, extra[0]]), np.concatenate([y, np.asarray(extra[1], bool)])


def extra_without(extra: Extra | None, group: str) -> Extra | None:
    """The extra rows that do not belong to ``group``."""
    if extra is None:
        return None
    keep = ~_held(extra[2], group)
    return extra[0][keep], extra[1][keep], extra[2][keep]


Fits = dict[frozenset, tuple[np.ndarray, np.ndarray, list]]
"""Ridge fits by the groups left out of their training rows: inside one ``nested_holdout`` the fit without {g, h}
is met twice (g reported and h held out to choose its lambda, and the other way round), on the very same rows."""


def held_out_scores(x: np.ndarray, y: np.ndarray, groups: np.ndarray,
                    lambdas: Sequence[float] = LAMBDAS, extra: Extra | None = None, *,
                    fits: Fits | None = None, without: frozenset = frozenset(),
                    floor: float = 0.0) -> dict[float, np.ndarray]:
    """For every lambda, each frame's ridge score from a fit without its group (no calibration: ranks only).
    ``fits``: fits already made on the same rows, by the groups left out (``without`` those of the caller), all
    with this ``floor`` (``standard_scale``)."""
    out = {lam: np.zeros(len(y)) for lam in lambdas}
    for g in group_names(groups):
        held = _held(groups, g)
        key = without | {g}
        if fits is None or key not in fits:
            made = _ridge_all(*with_extra(x[~held], y[~held], extra_without(extra, g)), lambdas, floor)
            if fits is None:
                mean, scale, per_lambda = made
            else:
                fits[key] = made
        if fits is not None:
            mean, scale, per_lambda = fits[key]
        z = (x[held] - mean) / scale
        for lam, (w, offset) in zip(lambdas, per_lambda, strict=True):
            out[lam][held] = z @ w + offset
    return out


def group_mean_auroc(scores: np.ndarray, y: np.ndarray, groups: np.ndarray) -> float:
    """Mean over groups of each group's AUROC (a one-class group against the other class of the rest)."""
    return float(np.mean([subset_auroc(scores, y, _held(groups, g)) for g in group_names(groups)]))


def choose_lambda(x: np.ndarray, y: np.ndarray, groups: np.ndarray, lambdas: Sequence[float] = LAMBDAS,
                  extra: Extra | None = None, *, fits: Fits | None = None,
                  without: frozenset = frozenset(), floor: float = 0.0) -> float:
    """The ridge strength whose leave-one-group-out scores have the best mean per-group AUROC."""
    scores = held_out_scores(x, y, groups, lambdas, extra, fits=fits, without=without, floor=floor)
    return max(lambdas, key=lambda lam: (group_mean_auroc(scores[lam], y, groups), lam))


def nested_holdout(x: np.ndarray, y: np.ndarray, groups: np.ndarray, lambdas: Sequence[float] = LAMBDAS,
                   extra: Extra | None = None, *, floor: float = 0.0) -> tuple[np.ndarray, dict[str, float]]:
    """Each frame's head probability from a head trained and tuned without its group, and each group's lambda.
    ``extra`` rows are trained on wherever none of their groups is held out; ``floor``: ``standard_scale``'s."""
    y = np.asarray(y, dtype=bool)
    out = np.zeros(len(y))
    chosen: dict[str, float] = {}
    fits: Fits = {}  # each inner fit is needed twice: made once (13 groups: 78 fits, not 156)
    for g in group_names(groups):
        held = _held(groups, g)
        extra_g = extra_without(extra, g)
        lam = choose_lambda(x[~held], y[~held], groups[~held], lambdas, extra_g, fits=fits, without=frozenset({g}),
                            floor=floor)
        head = fit(*with_extra(x[~held], y[~held], extra_g), lam, calibrate=int((~held).sum()), floor=floor)
        out[held] = 1.0 / (1.0 + np.exp(-(x[held] @ head.w + head.b)))
        chosen[str(g)] = lam
    return out, chosen


def frame_scenes(encoder: ImageNetEncoder, frames: Sequence[LabelledFrame], batch: int = 8) -> SceneInput:
    """The frames' view features ((N, V, 1280): the whole frame's pooled features first, then the regions) and
    small frames, what the heads are trained on."""
    return image_scenes(encoder, [f.image for f in frames], batch)


def image_scenes(encoder: ImageNetEncoder, images: Sequence[np.ndarray], batch: int = 8) -> SceneInput:
    """The view features and small frames of BGR images, encoded ``batch`` at a time."""
    parts = [encoder.scene_of(encoder.encode_images(list(images[i:i + batch])))
             for i in range(0, len(images), batch)]
    if not parts:
        return encoder.scene_of(encoder.encode_images([]))
    return SceneInput(np.concatenate([p.views for p in parts]).astype(np.float64),
                      np.concatenate([p.pixels for p in parts]))


def train_head(frames: Sequence[LabelledFrame], features: np.ndarray, *, concept: str, classes: Sequence[int],
               backbone: str = "lite0", colour: str = "none", lambdas: Sequence[float] = LAMBDAS,
               reads: str = "pooled", extra: Extra | None = None, floor: float = 0.0) -> tuple[LinearHead, dict]:
    """The head for ``concept`` trained on every frame (and the ``extra`` rows), its strength chosen by
    leave-one-group-out; and the leave-one-group-out figures at that strength (per group, group mean, pooled).
    ``floor`` (``standard_scale``) is recorded in the head, so that a refit without a group trains the same way."""
    y = np.array([f.fish for f in frames])
    groups = np.array([f.group for f in frames])
    scores = held_out_scores(features, y, groups, lambdas, extra, floor=floor)
    lam = max(lambdas, key=lambda v: (group_mean_auroc(scores[v], y, groups), v))
    result = fit(*with_extra(features, y, extra), lam, calibrate=len(y), floor=floor)
    figures = {"lambda": lam, "group_mean_auroc": group_mean_auroc(scores[lam], y, groups),
               "pooled_auroc": float(auroc(scores[lam], y)),
               "groups": {g: float(subset_auroc(scores[lam], y, _held(groups, g))) for g in group_names(groups)}}
    sources: dict[str, int] = {}
    for f in frames:
        sources[f.source] = sources.get(f.source, 0) + 1
    trained_on = {"command": "merlion eval train-head --data ../shared/data --out <file>", "frames": len(frames),
                  "positives": int(y.sum()), "sources": sources, "lambda": lam,
                  "logo_group_mean_auroc": round(figures["group_mean_auroc"], 4)}
    if floor:
        trained_on["scale_floor"] = floor
    if extra is not None and len(extra[0]):
        trained_on["extra_rows"] = {"rows": len(extra[0]), "positives": int(np.sum(extra[1]))}
    head = LinearHead(concept=concept, classes=tuple(int(c) for c in classes), backbone=backbone, colour=colour,
                      w=result.w, b=result.b, trained_on=trained_on, input=reads)
    return head, figures


def held_out_head(encoder: Encoder, presampler: PreSampler, features: np.ndarray,
                  frames: Sequence[LabelledFrame]) -> dict:
    """Per-group AUROC where the head that answers the query never saw the group: retrained without it at the
    shipped head's strength. Without a head for the query, the scores involve no learning from these frames and
    the configured scores are reported as they are."""
    head_of = getattr(encoder, "head_of", None)
    head = head_of(presampler.text_embeddings) if head_of else None
    if head is None:
        return {"method": "no learned head answers the query: the configured scores, nothing learned from the data",
                "by_group": {}, "deepfish_habitats": {}}
    lam = float(head.trained_on.get("lambda", LAMBDAS[1]))
    y = np.array([f.fish for f in frames])
    groups = np.array([f.group for f in frames])
    floor = float(head.trained_on.get("scale_floor", 0.0))
    scores = held_out_scores(np.asarray(features, np.float64), y, groups, [lam], floor=floor)[lam]
    by_group = per_group(scores, frames)
    return {"method": f"{head.concept} head retrained without each group (lambda {lam:g})", "by_group": by_group,
            "deepfish_habitats": spread(by_group, DEEPFISH)}
