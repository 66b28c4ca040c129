"""Enhance image files, folders of images and video files on disk (``merlion enhance``).

Outputs keep their input names, so an enhanced folder lines up with the raw one file for file; an output that
would land on an input is refused before anything is written, so raw footage is never lost.
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from companion.errors import MerlionError, UsageError
from companion.vision.enhancers.base import Enhancer

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")


@dataclass
class EnhanceReport:
    written: list[Path] = field(default_factory=list)
    failed: list[tuple[Path, str]] = field(default_factory=list)
    frames: int = 0


def list_images(folder: Path) -> list[Path]:
    """Image files directly in ``folder``, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def side_by_side(raw: np.ndarray, enhanced: np.ndarray) -> np.ndarray:
    """Raw on the left, enhanced on the right, for a quick visual check."""
    return np.hstack([raw, enhanced])


def _plan(src: Path, dst: Path) -> list[tuple[Path, Path]]:
    if not src.exists():
        raise UsageError(f"{src}: no such file or folder")
    if src.is_dir():
        inputs = list_images(src)
        if not inputs:
            raise UsageError(f"{src}: no images in this folder ({', '.join(IMAGE_SUFFIXES)})")
        if dst.exists() and not dst.is_dir():
            raise UsageError(f"{dst}: is a file; the output of a folder must be a folder")
        pairs = [(p, dst / p.name) for p in inputs]
    else:
        if src.suffix.lower() not in IMAGE_SUFFIXES + VIDEO_SUFFIXES:
            raise UsageError(f"{src}: not an image or video file ({src.suffix or 'no suffix'})")
        target = dst / src.name if dst.is_dir() else dst
        kind = VIDEO_SUFFIXES if src.suffix.lower() in VIDEO_SUFFIXES else IMAGE_SUFFIXES
        if target.suffix.lower() not in kind:
            what = "a video" if kind is VIDEO_SUFFIXES else "an image"
            raise UsageError(f"{dst}: output must be a folder or {what} file name like the input {src.name}")
        pairs = [(src, target)]
    inputs_resolved = {p.resolve() for p, _ in pairs}
    for _, out in pairs:
        if out.resolve() in inputs_resolved or (out.exists() and out.resolve() == src.resolve()):
            raise UsageError(f"{out}: would overwrite an input; choose another output")
    return pairs


def _enhance_video(enhancer: Enhancer, src: Path, dst: Path, sbs: bool, progress: bool) -> int:
    cap = cv2.VideoCapture(str(src))
    if not cap.isOpened():
        raise MerlionError(f"{src}: OpenCV cannot open this video")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or None
    writer = None
    tmp = dst.with_name(f".{dst.stem}.partial{dst.suffix}")
    frames = 0
    try:
        with tqdm(total=total, desc=src.name, unit="frame", disable=not progress) as bar:
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                out = enhancer.enhance(frame)
                if sbs:
                    out = side_by_side(frame, out)
                if writer is None:
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                             (out.shape[1], out.shape[0]))
                    if not writer.isOpened():
                        raise MerlionError(f"{dst}: OpenCV cannot write a video here")
                writer.write(out)
                frames += 1
                bar.update(1)
    finally:
        cap.release()
        if writer is not None:
            writer.release()
    if frames == 0:
        tmp.unlink(missing_ok=True)
        raise MerlionError(f"{src}: no frames could be read")
    tmp.replace(dst)
    return frames


def enhance_path(enhancer: Enhancer, src: str | Path, dst: str | Path, *, sbs: bool = False,
                 progress: bool | None = None) -> EnhanceReport:
    """Enhance one image, one video, or every image in a folder into ``dst`` (names kept).

    Unreadable images are reported and skipped; everything else is written as it is done.
    """
    src, dst = Path(src), Path(dst)
    pairs = _plan(src, dst)
    if progress is None:
        progress = sys.stderr.isatty()
    if src.is_dir():
        try:
            dst.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise MerlionError(f"{dst}: cannot create the output folder ({err.strerror or err})") from None
    else:
        dst_parent = pairs[0][1].parent
        if not dst_parent.is_dir():
            raise UsageError(f"{dst_parent}: no such folder")
    report = EnhanceReport()
    if len(pairs) == 1 and src.suffix.lower() in VIDEO_SUFFIXES:
        report.frames = _enhance_video(enhancer, src, pairs[0][1], sbs, progress)
        report.written.append(pairs[0][1])
        return report
    for inp, out in tqdm(pairs, desc="enhance", unit="image", disable=not progress):
        image = cv2.imread(str(inp), cv2.IMREAD_COLOR)
        if image is None:
            report.failed.append((inp, "not a readable image"))
            log.warning("%s: not a readable image, skipped", inp)
            continue
        result = enhancer.enhance(image)
        if sbs:
            result = side_by_side(image, result)
        if not cv2.imwrite(str(out), result):
            raise MerlionError(f"{out}: cannot write the enhanced image")
        report.written.append(out)
        report.frames += 1
    return report
