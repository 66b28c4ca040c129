"""Measurements of an enhancer: speed, image quality, and what it does to the fish/no-fish separation.

Why three: speed decides whether the enhancer can keep up on the vehicle; PSNR/SSIM against references and the
no-reference UCIQE/UIQM say whether the pictures look better; but what MERLION-E is for is the encoder's
semantic score, so the last measure asks whether enhancement makes fish frames and empty frames easier to tell
apart (AUROC and the mean score gap, with and without enhancement, on labelled real footage).
"""

from __future__ import annotations

import csv
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config, QueryConfig
from companion.errors import MerlionError, UsageError
from companion.evaluation.roc import auroc
from companion.vision import image_quality as iq
from companion.vision.encoders.base import Encoder
from companion.vision.enhancers.base import Enhancer
from companion.vision.enhancers.files import IMAGE_SUFFIXES, list_images

log = logging.getLogger(__name__)

DEFAULT_LIVE_SIZE = (640, 480)
"""Live frame size when the config names none: the usual USB camera mode of a BlueROV2 companion."""


def live_size(cfg: Config) -> tuple[int, int]:
    """(width, height) of a live frame: the camera size asked in ``source``, else DEFAULT_LIVE_SIZE."""
    if cfg.source.width and cfg.source.height:
        return cfg.source.width, cfg.source.height
    return DEFAULT_LIVE_SIZE


def synthetic_murky_frames(count: int = 8, size: tuple[int, int] = (320, 240), seed: int = 0) -> list[np.ndarray]:
    """Hazy blue-green frames with texture, for timing when no images are given (speed does not depend on
    content much, but an all-flat frame would flatter the enhancer)."""
    rng = np.random.default_rng(seed)
    w, h = size
    out = []
    for _ in range(count):
        base = rng.integers(0, 256, size=(h // 8 + 1, w // 8 + 1, 3), dtype=np.uint8)
        tex = cv2.resize(base, (w, h), interpolation=cv2.INTER_CUBIC).astype(np.float32)
        veil = np.array([150.0, 130.0, 40.0], dtype=np.float32)  # BGR: blue-green water
        out.append(np.clip(0.45 * tex + 0.55 * veil, 0, 255).astype(np.uint8))
    return out


def load_images(paths: Sequence[str | Path]) -> list[tuple[Path, np.ndarray]]:
    """Images from files and folders (folders: their image files, sorted by name)."""
    files: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            files.extend(list_images(p))
        elif p.is_file():
            files.append(p)
        else:
            raise UsageError(f"{p}: no such file or folder")
    out = []
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            raise MerlionError(f"{f}: not a readable image ({', '.join(IMAGE_SUFFIXES)})")
        out.append((f, img))
    if paths and not out:
        raise UsageError(f"no images in {', '.join(map(str, paths))}")
    return out


def measure_speed(enhancer: Enhancer, frames: Sequence[np.ndarray], size: tuple[int, int], *,
                  seconds: float = 3.0, min_frames: int = 5, warmup: int = 2) -> tuple[float, float]:
    """(frames/s, CPU ms per frame) of ``enhancer.enhance`` on ``frames`` resized to ``size`` (resize not timed).

    CPU time (all threads of this process) is reported beside the wall-clock rate because on a shared machine
    the rate also measures the neighbours; the CPU cost is what the enhancer itself needs.
    """
    sized = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) if (f.shape[1], f.shape[0]) != size else f
             for f in frames]
    for i in range(warmup):
        enhancer.enhance(sized[i % len(sized)])
    n = 0
    start = time.perf_counter()
    cpu_start = time.process_time()
    while True:
        enhancer.enhance(sized[n % len(sized)])
        n += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds and n >= min_frames:
            return n / elapsed, (time.process_time() - cpu_start) * 1000.0 / n


def read_pairs(folder: str | Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """EUVP-style pairs: ``A/<name>`` degraded, ``GTr_A/<name>`` its reference (matched by file name)."""
    root = Path(folder)
    deg, ref = root / "A", root / "GTr_A"
    if not deg.is_dir() or not ref.is_dir():
        raise UsageError(f"{root}: expected sub-folders A/ (degraded) and GTr_A/ (reference)")
    out = []
    for p in list_images(deg):
        q = ref / p.name
        if not q.is_file():
            continue
        a, b = cv2.imread(str(p)), cv2.imread(str(q))
        if a is None or b is None:
            raise MerlionError(f"{p if a is None else q}: not a readable image")
        if a.shape != b.shape:
            b = cv2.resize(b, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_AREA)
        out.append((p.name, a, b))
    if not out:
        raise UsageError(f"{root}: no image in A/ has a namesake in GTr_A/")
    return out


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def quality_report(enhancer: Enhancer, pairs: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> dict:
    """PSNR/SSIM of degraded->reference and enhanced->reference, and UCIQE/UIQM of all three, as means."""
    rows: dict[str, list[float]] = {k: [] for k in (
        "psnr_degraded", "psnr_enhanced", "ssim_degraded", "ssim_enhanced",
        "uciqe_degraded", "uciqe_enhanced", "uciqe_reference", "uiqm_degraded", "uiqm_enhanced", "uiqm_reference")}
    for _, deg, ref in pairs:
        enh = enhancer.enhance(deg)
        rows["psnr_degraded"].append(iq.psnr(deg, ref))
        rows["psnr_enhanced"].append(iq.psnr(enh, ref))
        rows["ssim_degraded"].append(iq.ssim(deg, ref))
        rows["ssim_enhanced"].append(iq.ssim(enh, ref))
        for name, img in (("degraded", deg), ("enhanced", enh), ("reference", ref)):
            rows[f"uciqe_{name}"].append(iq.uciqe(img))
            rows[f"uiqm_{name}"].append(iq.uiqm(img))
    return {"pairs": len(pairs), **{k: round(_mean(v), 4) for k, v in rows.items()}}


def no_reference_report(enhancer: Enhancer, images: Sequence[np.ndarray]) -> dict:
    """UCIQE/UIQM before and after enhancement (means), for footage without references."""
    enhanced = [enhancer.enhance(img) for img in images]
    return {
        "images": len(images),
        "uciqe_raw": round(_mean([iq.uciqe(i) for i in images]), 4),
        "uciqe_enhanced": round(_mean([iq.uciqe(i) for i in enhanced]), 4),
        "uiqm_raw": round(_mean([iq.uiqm(i) for i in images]), 4),
        "uiqm_enhanced": round(_mean([iq.uiqm(i) for i in enhanced]), 4),
    }


@dataclass
class LabelledSet:
    name: str
    images: list[np.ndarray]
    fish: np.ndarray


LABELLED_SETS = ("suim", "survey")


def load_labelled(data_dir: str | Path, names: Sequence[str] = LABELLED_SETS) -> list[LabelledSet]:
    """The fish-labelled real footage in ../shared/data: SUIM stills and every frame of the survey video."""
    root = Path(data_dir)
    sets: list[LabelledSet] = []
    suim = root / "suim" / "labels.csv"
    if "suim" in names and suim.is_file():
        imgs, labels = [], []
        with suim.open(newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                img = cv2.imread(str(root / "suim" / "images" / row["image"]))
                if img is None:
                    raise MerlionError(f"{root / 'suim' / 'images' / row['image']}: not a readable image")
                imgs.append(img)
                labels.append(int(row["fish_present"]))
        sets.append(LabelledSet("suim", imgs, np.array(labels, dtype=bool)))
    survey = root / "survey" / "survey_480x270.mp4"
    survey_labels = root / "survey" / "survey_480x270_labels.csv"
    if "survey" in names and survey.is_file() and survey_labels.is_file():
        with survey_labels.open(newline="", encoding="utf-8") as fh:
            by_frame = {int(r["frame_index"]): int(r["fish_present"]) for r in csv.DictReader(fh)}
        cap = cv2.VideoCapture(str(survey))
        imgs, labels = [], []
        index = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if index in by_frame:
                imgs.append(frame)
                labels.append(by_frame[index])
            index += 1
        cap.release()
        sets.append(LabelledSet("survey", imgs, np.array(labels, dtype=bool)))
    if not sets:
        raise UsageError(f"{root}: none of {', '.join(names)} is there (suim/labels.csv, "
                         "survey/survey_480x270.mp4 with its labels)")
    return sets


def _scores(encoder: Encoder, text: np.ndarray, images: Sequence[np.ndarray]) -> np.ndarray:
    return np.asarray(encoder.semantic_scores(encoder.encode_images(images), text), dtype=np.float64)


def _separation(scores: np.ndarray, fish: np.ndarray) -> dict:
    both = fish.any() and (~fish).any()
    return {
        "auroc": round(auroc(scores, fish), 4) if both else None,
        "gap": round(float(scores[fish].mean() - scores[~fish].mean()), 4) if both else None,
    }


def separation_report(encoder: Encoder, queries: QueryConfig, enhancer: Enhancer, sets: Sequence[LabelledSet],
                      *, tau_ses: float) -> dict:
    """Fish/no-fish separation of the semantic score on raw frames, on enhanced frames, and what the selective
    MERLION-E rule (enhance when ss > tau_ss, keep when ss_e > tau_ses) lets through, per set and pooled."""
    text = encoder.encode_texts([queries.positive, *queries.negatives])
    out: dict = {"encoder": encoder.describe().get("name", ""), "tau_ss": queries.tau_ss, "tau_ses": tau_ses}
    pooled_raw, pooled_enh, pooled_fish = [], [], []
    for s in sets:
        raw = _scores(encoder, text, s.images)
        enh = _scores(encoder, text, [enhancer.enhance(i) for i in s.images])
        out[s.name] = _set_report(raw, enh, s.fish, queries.tau_ss, tau_ses)
        pooled_raw.append(raw)
        pooled_enh.append(enh)
        pooled_fish.append(s.fish)
    out["all"] = _set_report(np.concatenate(pooled_raw), np.concatenate(pooled_enh), np.concatenate(pooled_fish),
                             queries.tau_ss, tau_ses)
    return out


def _set_report(raw: np.ndarray, enh: np.ndarray, fish: np.ndarray, tau_ss: float, tau_ses: float) -> dict:
    passed = raw > tau_ss
    kept = passed & (enh > tau_ses)

    def rates(mask: np.ndarray) -> dict:
        return {"fish_kept": int((mask & fish).sum()), "nofish_kept": int((mask & ~fish).sum())}

    return {
        "frames": int(fish.size), "fish": int(fish.sum()),
        "raw": _separation(raw, fish), "enhanced": _separation(enh, fish),
        "filter_raw": rates(passed), "filter_selective": rates(kept),
    }
