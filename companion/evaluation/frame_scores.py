"""The semantic score of every frame of a video, for AUROC and for the score-over-time plot.

Reads the file with OpenCV in source order (no subsampling: labels are per source frame) and scores in batches
exactly as the pipeline does: the same downscale (``pipeline.downscale_for``) and the same pre-sampler
(``companion.vision.presampler``, which adds the generic negative when no negative query is given).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from companion.config import QueryConfig
from companion.errors import MerlionError, UsageError
from companion.vision.encoders.base import Encoder
from companion.vision.pipeline import downscale_for
from companion.vision.presampler import PreSampler


@dataclass
class VideoScores:
    indices: list[int]
    """0-based source frame of each score."""
    times: list[float]
    scores: np.ndarray
    fps: float


def score_video(path: str | Path, encoder: Encoder, queries: QueryConfig, batch: int = 8) -> VideoScores:
    """Scores every frame of ``path`` against ``[positive, *negatives]``."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"{p}: no such video file")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        raise MerlionError(f"{p}: OpenCV cannot open this video")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    presampler = PreSampler(encoder, queries.positive, queries.negatives, queries.tau_ss)
    indices: list[int] = []
    scores: list[np.ndarray] = []
    pending: list[np.ndarray] = []

    def flush() -> None:
        if pending:
            scores.append(presampler.scores(encoder.encode_images(pending)))
            pending.clear()

    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or None
    bar = tqdm(total=total, unit="frame", desc="score", file=sys.stderr, disable=not sys.stderr.isatty())
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            indices.append(len(indices))
            pending.append(downscale_for(img, encoder.input_size))
            if len(pending) >= batch:
                flush()
                bar.update(batch)
        flush()
    finally:
        cap.release()
        bar.close()
    if not indices:
        raise MerlionError(f"{p}: no frames could be decoded")
    return VideoScores(indices, [i / fps for i in indices], np.concatenate(scores).astype(np.float64), fps)
