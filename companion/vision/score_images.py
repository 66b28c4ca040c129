"""Scores still images against the queries: what `merlion score` prints, one image at a time.

It uses the same encoder factory and pre-sampler as the pipeline, so a score printed here is the ss_t a frame
with the same pixels would get in `merlion summarize` (before any resizing the source does).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config
from companion.sources.folder import collect_images
from companion.vision.dive_mean import DiveWindow
from companion.vision.encoders.base import Encoder
from companion.vision.feedback import read_mark_images, with_marks
from companion.vision.presampler import PreSampler
from companion.vision.topics import score_matrix

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ImageScore:
    file: Path
    score: float | None
    """None when the file could not be decoded (``error`` says why); with several topics the highest."""
    error: str = ""
    topics: dict[str, float] = field(default_factory=dict)
    """Each topic's score, by name (one entry with one topic)."""


def score_images(cfg: Config, paths: Sequence[str | Path], encoder: Encoder | None = None, *,
                 like: Sequence[str | Path] = (), unlike: Sequence[str | Path] = (),
                 dive: bool = False) -> Iterator[ImageScore]:
    """Yield each image's score as soon as its batch is encoded (batches of ``cfg.encoder.batch``).

    ``dive``: the images are one dive's frames in order, so each is also judged against the scene of those before
    it (the scene residual, ``companion.vision.scene_memory``); by default photos are scored each on its own, since
    a folder of unrelated photos has no scene (docs/encoders.md).
    ``like``/``unlike``: marked example images (files or folders) combined with the query score
    (``companion.vision.feedback``).
    """
    files = collect_images(paths)
    like_images, unlike_images = read_mark_images(like, "--like"), read_mark_images(unlike, "--unlike")
    if encoder is None:
        from companion.vision.encoders.factory import make_encoder

        encoder = make_encoder(cfg.encoder)
    topics = cfg.queries.topic_list()
    window = DiveWindow()  # the images scored so far, in order: one for every topic, fed once per image
    presamplers = [PreSampler(encoder, t.positive, t.negatives, cfg.queries.tau_ss, window) for t in topics]
    presamplers[0] = with_marks(presamplers[0], like_images, unlike_images)  # marks teach the first topic
    batch = cfg.encoder.batch
    for start in range(0, len(files), batch):
        chunk = files[start:start + batch]
        images: list[np.ndarray] = []
        readable: list[Path] = []
        errors: dict[Path, str] = {}
        for f in chunk:
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None:
                errors[f] = "cannot decode as an image"
            else:
                images.append(img)
                readable.append(f)
        emb = encoder.encode_images(images) if images else None  # one pass serves every topic
        scene = encoder.scene_input(emb) if images and dive else None
        scores = (score_matrix(presamplers, emb, window.take(encoder.sampler_features(emb), scene=scene))[0]
                  if images else np.zeros((0, len(topics))))
        by_file = dict(zip(readable, scores, strict=True))
        for f in chunk:
            if f in errors:
                yield ImageScore(f, None, errors[f])
            else:
                row = by_file[f]
                yield ImageScore(f, float(row.max()), topics={t.name: float(v) for t, v in zip(topics, row, strict=True)})
