"""Training frames for the scene head: real empty frames of a fish habitat with real fish pasted into them.

The scene head learns what a fish adds to a frame against the frames before it in the same dive. The shared data
has 30 fish frames per DeepFish habitat, and in some habitats the fish are a few pixels wide in haze (7393), a
case the other habitats barely teach. Pasting fish cut from another source's labelled boxes (the aquarium frames'
Pascal-VOC boxes) into each habitat's own empty frames, small and taking on the water's colour, gives the head
positives whose only difference from a real empty frame of the same scene is the fish. They are training rows
only, never scored or reported, and each carries the groups of both its frame and its fish
(``"deepfish:7117+aquarium"``), so a head reported on a habitat, or on the aquarium, never saw them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import MerlionError
from companion.evaluation.head_training import image_scenes
from companion.evaluation.sources import DEEPFISH, GROUPS, LabelledFrame
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.scene_memory import SceneInput

CROPS_FOLDER = "aquarium_fish/frames"
CROPS_GROUP = GROUPS["aquarium_frames"]
PER_FRAME = 2
"""Pasted copies made of each empty frame (each with 1 to 3 fish)."""
SEED = 7
WIDTH = (8.0, 48.0)
"""A pasted fish's width in pixels of a 360-pixel-wide frame (DeepFish's fish are 5 to 60)."""
HAZE = (0.1, 0.6)
"""How far a pasted fish is blended toward the mean colour of the water it covers."""
MIN_BOX = (30, 15)
"""Boxes no larger than this (width, height in the source frame) are not cut: too few pixels of fish."""


@dataclass(frozen=True)
class PastedFish:
    """Pasted frames: the empty frame each was made from (an index into the labelled frames), its groups, and
    the encoder's view features and small frame of the pasted image."""

    base: np.ndarray
    groups: np.ndarray
    scene: SceneInput


def fish_crops(root: str | Path) -> list[np.ndarray]:
    """Every labelled fish box of the aquarium frames, cut out (BGR)."""
    folder = Path(root) / CROPS_FOLDER
    crops = []
    for label in sorted(folder.glob("*.xml")):
        image = cv2.imread(str(label.with_suffix(".jpg")))
        if image is None:
            raise MerlionError(f"{label.with_suffix('.jpg')}: missing or unreadable (its boxes are in {label.name})")
        try:
            boxes = [[float(box.findtext(k, "nan")) for k in ("xmin", "ymin", "xmax", "ymax")]
                     for box in ET.parse(label).getroot().iter("bndbox")]
        except (ET.ParseError, ValueError) as exc:
            raise MerlionError(f"{label}: not a Pascal-VOC box file ({exc})") from None
        for x0, y0, x1, y1 in boxes:
            if not np.isfinite([x0, y0, x1, y1]).all():
                raise MerlionError(f"{label}: a box lacks one of xmin, ymin, xmax, ymax")
            crop = image[max(int(y0), 0):max(int(y1), 0), max(int(x0), 0):max(int(x1), 0)]
            if crop.shape[1] > MIN_BOX[0] and crop.shape[0] > MIN_BOX[1]:  # what was cut, not what was claimed
                crops.append(crop.copy())
    if not crops:
        raise MerlionError(f"{folder}: no fish boxes to paste (Pascal-VOC .xml beside each .jpg)")
    return crops


def paste(frame: np.ndarray, crops: Sequence[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """A copy of ``frame`` with 1 to 3 fish pasted in: an elliptic, feathered cut of each crop, scaled to a
    small fish and blended toward the colour of the water it covers."""
    out = frame.astype(np.float32)
    height, width = out.shape[:2]
    for _ in range(rng.integers(1, 4)):
        crop = crops[rng.integers(len(crops))]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        w = int(rng.uniform(*WIDTH) * width / 360)
        h = max(3, int(w * crop.shape[0] / crop.shape[1]))
        if h >= height or w >= width:
            continue
        fish = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
        x, y = rng.integers(0, width - w), rng.integers(0, height - h)
        mask = np.zeros((h, w), np.float32)
        cv2.ellipse(mask, (w // 2, h // 2), (max(1, int(w * 0.45)), max(1, int(h * 0.4))), 0, 0, 360, 1.0, -1)
        mask = cv2.GaussianBlur(mask, (0, 0), max(0.5, w / 12))[..., None]
        water = out[y:y + h, x:x + w]
        haze = rng.uniform(*HAZE)
        fish = (1 - haze) * fish + haze * water.mean(axis=(0, 1))
        out[y:y + h, x:x + w] = mask * fish + (1 - mask) * water
    return np.clip(out, 0, 255).astype(np.uint8)


def pasted_images(frames: Sequence[LabelledFrame], crops: Sequence[np.ndarray], *, per_frame: int = PER_FRAME,
                  seed: int = SEED) -> tuple[np.ndarray, list[np.ndarray]]:
    """(base indices, images): ``per_frame`` pasted copies of every empty DeepFish frame, reproducibly."""
    rng = np.random.default_rng(seed)
    base, images = [], []
    for i, frame in enumerate(frames):
        if frame.source.startswith(DEEPFISH) and not frame.fish:
            for _ in range(per_frame):
                base.append(i)
                images.append(paste(frame.image, crops, rng))
    return np.array(base, dtype=int), images


def pasted_fish(encoder: ImageNetEncoder, frames: Sequence[LabelledFrame], crops: Sequence[np.ndarray]
                ) -> PastedFish:
    """The pasted frames of ``frames`` and their scene input from the packaged ``encoder``; ``crops`` from
    ``fish_crops``, read before any long work so that a data folder without boxes fails at once."""
    base, images = pasted_images(frames, crops)
    groups = np.array([f"{frames[i].group}+{CROPS_GROUP}" for i in base])
    return PastedFish(base=base, groups=groups, scene=image_scenes(encoder, images))
