"""Small learned heads on the packaged encoder's pooled features: a concept scored from real underwater data.

ImageNet's fish classes were learned from air-lit photos of fish held by anglers; on sea-bed footage their
probability mass ranks fish frames at chance (DeepFish AUROC 0.49). A logistic regression on the same
network's 1280 pooled features, trained on labelled underwater frames (``companion.evaluation.head_training``),
ranks them far better on habitats it never saw (docs/encoders.md). A head stands for one concept: it applies
when the positive query's ImageNet classes are (nearly) the classes the head was trained for, so "fish" uses the
head and "shark" or "coral" keep the lexical class mapping.

A head is a JSON file (a few KB): the concept, its ImageNet classes, the colour handling its features were
taken with, weights ``w`` and bias ``b`` on raw pooled features (standardisation is folded in), and what it was
trained on. Shipped heads live in ``companion/vision/encoders/heads/``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.atomic_write import atomic_write
from companion.errors import MerlionError
from companion.output_path import check_target

HEADS_DIR = Path(__file__).with_name("heads")
SURE = 0.998
"""The most (and 1 - SURE the least) a head's probability may say. A head fitted on a few hundred frames is
overconfident on footage like what it was trained on (sigmoid 1.0 in float32), which made the top of tau_ss's
range (MERL_TAU_SS up to 0.999) a gate that such frames still passed; an affine squash keeps every ranking."""
MIN_OVERLAP = 0.5
"""Jaccard overlap between a query's classes and a head's classes above which the head answers the query."""


@dataclass(frozen=True)
class LinearHead:
    """``p = sigmoid(features . w + b)``: the probability that a frame shows the concept."""

    concept: str
    classes: tuple[int, ...]
    backbone: str
    colour: str
    w: np.ndarray
    b: float
    trained_on: dict = field(default_factory=dict)
    input: str = "pooled"
    """What the head reads: "pooled" (the frame's pooled features) or "scene" (the frame's scene residual,
    ``companion.vision.scene_memory``: needs the dive's frames before it)."""

    def logits(self, features: np.ndarray) -> np.ndarray:
        return np.asarray(features, dtype=np.float64) @ self.w + self.b

    def probabilities(self, features: np.ndarray) -> np.ndarray:
        sure = 1.0 / (1.0 + np.exp(-self.logits(features)))
        return (1.0 - SURE) + (2.0 * SURE - 1.0) * sure

    def matches(self, class_weights: np.ndarray) -> bool:
        """Whether a query's class weights (1000,) name this head's concept (Jaccard of the class sets)."""
        query = set(np.flatnonzero(np.asarray(class_weights) > 0).tolist())
        mine = set(self.classes)
        union = query | mine
        return bool(union) and len(query & mine) / len(union) >= MIN_OVERLAP

    def to_json(self) -> dict:
        return {"concept": self.concept, "classes": list(self.classes), "backbone": self.backbone,
                "colour": self.colour,
                "input": self.input, "b": round(float(self.b), 6), "w": [float(f"{v:.5g}") for v in self.w],
                "trained_on": self.trained_on}

    def save(self, path: str | Path) -> Path:
        p = check_target(path)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(p, json.dumps(self.to_json(), separators=(",", ":")) + "\n")  # a head is never half-written
        except OSError as err:
            raise MerlionError(f"{p}: cannot write ({err.strerror})") from None
        return p


def load_head(path: str | Path) -> LinearHead:
    """A head from its JSON file; MerlionError naming the file when it is unreadable or malformed."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        return LinearHead(concept=str(data["concept"]), classes=tuple(int(c) for c in data["classes"]),
                          backbone=str(data.get("backbone", "lite0")), colour=str(data.get("colour", "none")), w=np.asarray(data["w"], dtype=np.float64),
                          b=float(data["b"]), trained_on=dict(data.get("trained_on") or {}),
                          input=_input(data.get("input", "pooled")))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise MerlionError(f"{p}: not a readable learned head ({err})") from None


INPUTS = ("pooled", "scene")


def _input(value: object) -> str:
    if value not in INPUTS:
        raise ValueError(f"input {value!r} is not one of {', '.join(INPUTS)}")
    return str(value)


def shipped_heads(backbone: str, widths: dict[str, int], colour: str) -> list[LinearHead]:
    """The heads shipped with the package that fit an encoder with this backbone and colour, and whose input has
    the length the encoder gives (``widths``: per input; a head trained on an older layout is left out)."""
    heads = sorted((load_head(p) for p in sorted(HEADS_DIR.glob("*.json"))), key=lambda h: h.input != "pooled")
    return [h for h in heads if h.backbone == backbone and h.colour == colour
            and h.w.shape == (widths.get(h.input, -1),)]


def head_for(heads: list[LinearHead], class_weights: np.ndarray, reads: str = "pooled") -> LinearHead | None:
    """The first head reading ``reads`` (its ``input``) whose concept the query names, else None (the lexical
    class mapping answers)."""
    return next((h for h in heads if h.input == reads and h.matches(class_weights)), None)
