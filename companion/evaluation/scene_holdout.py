"""The fish head on the scene residual (``companion.vision.scene_memory``), trained and reported honestly.

Each source is one dive, streamed in its own order (``dive_centring.stream_order``: videos in order, each
DeepFish habitat in a seeded random order, since its label file lists the fish frames first). A frame's scene
residual needs the frames before it in its dive, so the features depend on the order: every figure is given for
three orders. A dive's first frame has no scene and is scored by the pooled head, as the companion does. Both
heads are trained without the reported group, their ridge strengths chosen by leave-one-group-out on the other
groups (``head_training.nested_holdout``). With ``pasted`` (``pasted_fish``), the scene head also trains on
empty frames with fish pasted in, each judged as if it had come in place of its empty original.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np

from companion.evaluation.dive_centring import ORDER_SEED, ORDER_SEEDS, stream_order
from companion.evaluation.head_training import Extra, nested_holdout, train_head
from companion.evaluation.holdout import over_orders, per_group, spread
from companion.evaluation.pasted_fish import PastedFish
from companion.evaluation.roc import auroc
from companion.evaluation.sources import DEEPFISH, LabelledFrame
from companion.vision.encoders.learned_head import LinearHead
from companion.vision.scene_memory import SceneInput, SceneMemory

SCENE_LAMBDAS = (1e4, 3e4, 1e5)
"""Ridge strengths tried for the scene head (its features are smaller and sparser than the pooled ones)."""
SCENE_SCALE_FLOOR = 0.1
"""The scene head's floor under each feature's standardisation scale, as a share of the median feature's spread
(``head_training.standard_scale``): a residual channel that is all but dead where the head trains (non-zero in 14 of
some 1,270 rows) but fires on ROV footage would otherwise be stretched to z > 1,000 there. Set once, 2026-11-29,
from a reviewing helper's diagnosis; the pooled head, whose features are dense, has no floor."""
ORDER_FIGURES = {"deepfish_habitats_mean": "deepfish_habitats.mean", "deepfish_habitats_min": "deepfish_habitats.min",
                 "deepfish_pooled": "deepfish_pooled", "group_mean": "group_mean", "pooled": "pooled"}
"""The scene head's figures summarised over frame orders."""


def scene_features(scene: SceneInput, frames: Sequence[LabelledFrame], seed: int = ORDER_SEED, *,
                   by_clip: bool = False) -> np.ndarray:
    """(N, D) each frame's scene residual within its own source's stream (NaN for a stream's first frame)."""
    out = np.full((len(frames), scene.width), np.nan)
    for idx in stream_order(frames, seed, by_clip=by_clip):
        out[idx] = SceneMemory().residuals(scene[idx])
    return out


def pasted_scene_features(scene: SceneInput, frames: Sequence[LabelledFrame], pasted: PastedFish,
                          seed: int = ORDER_SEED, *, by_clip: bool = False) -> np.ndarray:
    """(M, D) each pasted frame's scene residual, as if it had come in place of its empty original: against a
    copy of the dive's memory as it stood before the original, the pasted frame joining it the way a real frame
    joins (NaN where the original was the dive's first frame)."""
    out = np.full((len(pasted.base), pasted.scene.width), np.nan)
    copies: dict[int, list[int]] = {}
    for k, i in enumerate(pasted.base):
        copies.setdefault(int(i), []).append(k)
    for idx in stream_order(frames, seed, by_clip=by_clip):
        memory = SceneMemory()
        for i in idx:
            if memory.seen:
                for k in copies.get(int(i), []):
                    out[k] = copy.deepcopy(memory).residuals(pasted.scene[k])[0]
            memory.residuals(scene[i])
    return out


def pasted_rows(scene: SceneInput, frames: Sequence[LabelledFrame], pasted: PastedFish | None,
                seed: int = ORDER_SEED, *, by_clip: bool = False) -> Extra | None:
    """The pasted frames as training-only rows for the scene head (all fish), or None."""
    if pasted is None or not len(pasted.base):
        return None
    x = pasted_scene_features(scene, frames, pasted, seed, by_clip=by_clip)
    ok = np.isfinite(x).all(axis=1)
    return x[ok], np.ones(int(ok.sum()), bool), pasted.groups[ok]


def held_out_scene(scene: SceneInput, frames: Sequence[LabelledFrame],
                   seeds: Sequence[int] = ORDER_SEEDS, pasted: PastedFish | None = None, *,
                   pixels: bool = True, by_clip: bool = False,
                   progress: Callable[[str], None] = lambda _: None) -> dict:
    """Per order: per-group AUROC of the scene head (pooled head on each dive's first frame), every choice made
    without the reported group; and the same for the pooled head alone, for comparison. Without ``pixels`` the
    head reads the view features' residual only (what the pixel changes add, measured); ``by_clip``: each clip
    its own dive (``stream_order``), the head trained and tested so."""
    y = np.array([f.fish for f in frames])
    groups = np.array([f.group for f in frames])
    deepfish = np.array([f.source.startswith(DEEPFISH) for f in frames])
    pooled, _ = nested_holdout(np.asarray(scene.views[:, 0], np.float64), y, groups)

    def figures(scores: np.ndarray) -> dict:
        by_group = per_group(scores, frames)
        others = [v for g, v in by_group.items() if g != "pooled"]
        return {"by_group": by_group, "deepfish_habitats": spread(by_group, DEEPFISH),
                "group_mean": float(np.mean(others)), "pooled": by_group["pooled"],
                "deepfish_pooled": float(auroc(scores[deepfish], y[deepfish]))}

    orders = {}
    for n, seed in enumerate(seeds, 1):
        progress(f"order seed {seed} ({n} of {len(seeds)})")
        x = scene_features(scene, frames, seed, by_clip=by_clip)[:, :None if pixels else scene.views.shape[2]]
        ok = np.isfinite(x).all(axis=1)
        scores = pooled.copy()
        extra = pasted_rows(scene, frames, pasted, seed, by_clip=by_clip)
        if extra is not None and not pixels:
            extra = (extra[0][:, :x.shape[1]], *extra[1:])
        scores[ok], chosen = nested_holdout(x[ok], y[ok], groups[ok], SCENE_LAMBDAS, extra, floor=SCENE_SCALE_FLOOR)
        orders[str(seed)] = {**figures(scores), "lambda": chosen}
    method = ("fish head on the scene residual (each dive's first frame: the pooled head), trained and tuned "
              "without each group, per frame order")
    if pasted is not None:
        method += (f"; also trained on {len(pasted.base)} pasted-fish copies of {len(set(pasted.base.tolist()))} "
                   "empty frames (less the copies of a dive's first frame)")
    if by_clip:
        method += "; each DeepFish clip its own dive (no change of clip inside a dive), trained and tested so"
    return {"method": method, "pooled_head": figures(pooled), "orders": orders,
            "over_orders": over_orders(orders, ORDER_FIGURES)}


def train_scene_head(frames: Sequence[LabelledFrame], scene: SceneInput, *, concept: str,
                     classes: Sequence[int], seed: int = ORDER_SEED,
                     pasted: PastedFish | None = None) -> tuple[LinearHead, dict]:
    """The shipped scene head: trained on every frame's scene residual (order ``seed``) but the dives' first,
    and on the pasted frames'."""
    x = scene_features(scene, frames, seed)
    ok = np.isfinite(x).all(axis=1)
    kept = [f for f, k in zip(frames, ok, strict=True) if k]
    head, figures = train_head(kept, x[ok], concept=concept, classes=classes, lambdas=SCENE_LAMBDAS, reads="scene",
                               extra=pasted_rows(scene, frames, pasted, seed), floor=SCENE_SCALE_FLOOR)
    head.trained_on.update(command="merlion eval train-head --data ../shared/data --out <file> --scene-out <file>",
                           order_seed=seed)
    return head, figures
