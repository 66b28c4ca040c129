"""Per-source and leave-one-group-out AUROC: choosing an encoder setting by sources it was not tuned on.

A source with both classes (suim, survey) gets its own AUROC. A source with one class only (aquarium frames: all
fish; ROV clips: none) has no AUROC of its own, so it is ranked against the other class of every other source:
"are this source's fish frames above the no-fish frames we know of". Held-out choice: for each group in turn,
the setting with the best pooled AUROC on the frames outside the group is chosen, and reported on the group.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from companion.evaluation.roc import auroc
from companion.evaluation.sources import LabelledFrame


def _in_group(frame: LabelledFrame, group: str) -> bool:
    return group in frame.group.split("+")


def subset_auroc(scores: np.ndarray, fish: np.ndarray, chosen: np.ndarray) -> float:
    """AUROC of the chosen frames; a one-class choice is ranked against the other class of all other frames."""
    if fish[chosen].all() or not fish[chosen].any():
        other = ~chosen & (fish != fish[chosen][0])
        chosen = chosen | other
    return auroc(scores[chosen], fish[chosen])


def per_source(scores: Sequence[float], frames: Sequence[LabelledFrame]) -> dict[str, float]:
    """{source: AUROC} plus "pooled" over every frame."""
    s = np.asarray(scores, dtype=np.float64)
    fish = np.array([f.fish for f in frames])
    names = np.array([f.source for f in frames])
    out = {src: subset_auroc(s, fish, names == src) for src in dict.fromkeys(names)}
    out["pooled"] = auroc(s, fish)
    return out


def groups_of(frames: Sequence[LabelledFrame]) -> list[str]:
    return list(dict.fromkeys(g for f in frames for g in f.group.split("+")))


def leave_one_group_out(variants: Mapping[str, Sequence[float]], frames: Sequence[LabelledFrame]) -> list[dict]:
    """For each group held out: the variant best on the rest (pooled AUROC), and its AUROC on the group."""
    fish = np.array([f.fish for f in frames])
    rows = []
    for group in groups_of(frames):
        held = np.array([_in_group(f, group) for f in frames])
        tune = {name: auroc(np.asarray(s)[~held], fish[~held]) for name, s in variants.items()}
        best = max(tune, key=lambda n: (tune[n], n))
        rows.append({"held_out": group, "chosen": best, "tune_auroc": tune[best],
                     "held_out_auroc": subset_auroc(np.asarray(variants[best], np.float64), fish, held),
                     "all": {n: subset_auroc(np.asarray(s, np.float64), fish, held) for n, s in variants.items()}})
    return rows


def per_group(scores: Sequence[float], frames: Sequence[LabelledFrame]) -> dict[str, float]:
    """{group: AUROC} (a source shared by two groups counts in both), plus "pooled" over every frame."""
    s = np.asarray(scores, dtype=np.float64)
    fish = np.array([f.fish for f in frames])
    out = {g: subset_auroc(s, fish, np.array([_in_group(f, g) for f in frames])) for g in groups_of(frames)}
    out["pooled"] = auroc(s, fish)
    return out


def spread(aurocs: Mapping[str, float], prefix: str) -> dict[str, float]:
    """Mean, min, max and max - min of the groups whose name starts with ``prefix`` (e.g. DeepFish habitats)."""
    values = [v for k, v in aurocs.items() if k.startswith(prefix)]
    if not values:
        return {}
    return {"groups": len(values), "mean": float(np.mean(values)), "min": float(np.min(values)),
            "max": float(np.max(values)), "spread": float(np.max(values) - np.min(values))}


def over_orders(orders: Mapping[str, Mapping], figures: Mapping[str, str]) -> dict[str, dict[str, float]]:
    """Mean, min and max over frame orders of each figure (``figures``: name -> dotted path in an order's result):
    a dive-relative score depends on the order the frames came in, so one order's figure is one draw."""
    def read(o: Mapping, path: str) -> float:
        for key in path.split("."):
            o = o[key]
        return float(o)

    out = {}
    for name, path in figures.items():
        values = [read(o, path) for o in orders.values()]
        if values:
            out[name] = {"orders": len(values), "mean": float(np.mean(values)), "min": float(np.min(values)),
                         "max": float(np.max(values))}
    return out
