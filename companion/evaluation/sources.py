"""The labelled frames of ../shared/data grouped by SOURCE, for held-out (leave-one-source-out) evaluation.

A score tuned on frames of one video and reported on other frames of the same video says little about a dive
the project has never seen, so every frame here carries the source it came from, and a source is held out
whole. ``survey`` is cut from the aquarium video and the ROV clips, so it belongs to both of those groups and
is held out with them. ``euvp_pairs`` has no fish labels and is not used. DeepFish frames are one source per
habitat (``deepfish:7117``...): each habitat is one camera drop, its own group.

``murky`` makes a synthetic stress copy of a frame (RUIE-style green cast, haze, softness, lower resolution):
real murky labelled frames are what the shared data lacks, and these are documented as synthetic wherever
they are reported.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import MerlionError, UsageError
from companion.evaluation.datasets import csv_rows

AQUARIUM_VIDEO_STEP = 20
ROV_STEP = 6
GROUPS = {"suim": "suim", "aquarium_frames": "aquarium", "aquarium_video": "aquarium", "rov_clips": "rov",
          "survey": "aquarium+rov"}
"""Source -> independent group: sources of one group share footage and are held out together."""
DEEPFISH = "deepfish:"


@dataclass(frozen=True)
class LabelledFrame:
    source: str
    name: str
    fish: bool
    image: np.ndarray
    clip: str = ""
    """The video clip the frame was cut from, where the data says (DeepFish: each habitat's fish and empty frames
    come from different clips of its camera), else empty."""

    @property
    def group(self) -> str:
        source = self.source.removesuffix("~murky")
        return source if source.startswith(DEEPFISH) else GROUPS[source]


def murky(image: np.ndarray, seed: int = 0) -> np.ndarray:
    """A synthetic RUIE-style murky version: red absorbed, green-blue veil, softness, half resolution."""
    rng = np.random.default_rng(seed)
    f = image.astype(np.float32) / 255.0
    h, w = f.shape[:2]
    f = cv2.resize(cv2.resize(f, (max(1, w // 2), max(1, h // 2)), interpolation=cv2.INTER_AREA), (w, h))
    f = cv2.GaussianBlur(f, (0, 0), 1.2)
    transmission = 0.45 + 0.1 * rng.random()
    f = f * np.array([0.55, 0.95, 0.45], np.float32)  # BGR attenuation: red absorbed most, blue some
    veil = np.array([0.35, 0.55, 0.2], np.float32)    # green-cyan backscatter (BGR)
    f = transmission * f + (1 - transmission) * veil
    f += rng.normal(0.0, 0.015, f.shape).astype(np.float32)
    return np.clip(f * 255.0, 0, 255).astype(np.uint8)


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise MerlionError(f"{path}: cannot decode as an image")
    return img


def _rows(path: Path, columns: tuple[str, ...]) -> list[dict[str, str]]:
    """A label file's rows, or a one-line MerlionError naming the file (missing, unreadable, or lacking a column)."""
    rows = csv_rows(path, missing="missing from the shared data folder")
    missing = [c for c in columns if not rows or c not in rows[0]]
    if missing:
        raise MerlionError(f"{path}: needs a header with {', '.join(columns)} and one row per frame "
                           f"({missing[0]!r} is missing)")
    return rows


def _video_frames(path: Path, step: int) -> Iterator[tuple[int, np.ndarray]]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise MerlionError(f"{path}: OpenCV cannot open this video")
    try:
        i = 0
        while True:
            ok, img = cap.read()
            if not ok:
                break
            if i % step == 0:
                yield i, img
            i += 1
    finally:
        cap.release()


def load_deepfish(root: Path) -> list[LabelledFrame]:
    """DeepFish frames (``root/deepfish``), one source per habitat; none when the folder is absent."""
    labels = root / "deepfish" / "labels.csv"
    if not labels.is_file():
        return []
    rows = _rows(labels, ("file", "habitat_id", "fish_present"))
    return [LabelledFrame(f"{DEEPFISH}{r['habitat_id']}", r["file"], r["fish_present"] == "1",
                          _read(root / "deepfish" / r["file"]), r.get("video_clip") or "") for r in rows]


def load_sources(data: str | Path, *, survey: bool = True, stress: bool = False,
                 deepfish: bool = True) -> list[LabelledFrame]:
    """Every labelled frame of the shared data set folder ``data``; with ``stress`` also a murky copy of each."""
    root = Path(data)
    if not (root / "suim" / "labels.csv").is_file():
        raise UsageError(f"{root}: not the shared data folder (no suim/labels.csv)")
    out: list[LabelledFrame] = load_deepfish(root) if deepfish else []
    for row in _rows(root / "suim" / "labels.csv", ("image", "fish_present")):
        out.append(LabelledFrame("suim", row["image"], row["fish_present"] == "1",
                                 _read(root / "suim" / "images" / row["image"])))
    for path in sorted((root / "aquarium_fish" / "frames").glob("*.jpg")):
        out.append(LabelledFrame("aquarium_frames", path.name, True, _read(path)))  # every frame has boxes
    for i, img in _video_frames(root / "aquarium_fish" / "fish.mp4", AQUARIUM_VIDEO_STEP):
        out.append(LabelledFrame("aquarium_video", f"fish.mp4#{i}", True, img))
    for clip in sorted((root / "rov_clips").glob("*.mp4")):
        for i, img in _video_frames(clip, ROV_STEP):
            out.append(LabelledFrame("rov_clips", f"{clip.name}#{i}", False, img))
    if survey:
        video = root / "survey" / "survey_480x270.mp4"
        label_file = root / "survey" / "survey_480x270_labels.csv"
        labels = [r["fish_present"] == "1" for r in _rows(label_file, ("fish_present",))]
        for i, img in _video_frames(video, 1):
            if i >= len(labels):
                raise MerlionError(f"{label_file}: {len(labels)} rows, but {video.name} has more frames")
            out.append(LabelledFrame("survey", f"{video.name}#{i:03d}", labels[i], img))
    if stress:
        out += [LabelledFrame(f"{f.source}~murky", f.name, f.fish, murky(f.image, seed=i)) for i, f in enumerate(out)]
    return out
