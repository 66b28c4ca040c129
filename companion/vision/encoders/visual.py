"""The ROST-style baseline: semantic-agnostic visual features, so the sampler alone decides.

ROST (Girdhar and Dudek) describes frames by colour and local texture words and keeps the most surprising ones;
it has no notion of what the operator is looking for. This encoder gives the same online sampler that kind of
description, so MERLION and the baseline differ only in the features and the semantic filter:

* colour: an HSV histogram (16 hue x 4 saturation x 4 value bins), robust to small motion;
* texture: a histogram of uniform local binary patterns (59 bins) of the grey image;
* local features: ORB descriptors quantised to a bag of 64 binary words. ROST learns its vocabulary offline;
  we have none to ship, so the words are fixed pseudo-random 256-bit strings (seeded, identical on every run),
  which quantise descriptors by Hamming distance like a random-projection hash.

Each block is a distribution (sums to 1) and the three are averaged, so the feature is itself a probability
vector, which suits the Jensen-Shannon (or ROST's KL) distance. There is no text tower: ``encode_texts`` returns
a placeholder and every frame scores 1.0, so semantic pre-sampling passes everything, which is the baseline.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from companion.config import EncoderConfig
from companion.vision.encoders.base import Encoder

HSV_BINS = (16, 4, 4)
ORB_WORDS = 64
ORB_FEATURES = 300
VOCAB_SEED = 20240913
DEFAULT_SIZE = (320, 180)


def _uniform_lbp_table() -> np.ndarray:
    """Maps the 256 8-bit LBP codes to 59 bins: one per uniform pattern (<= 2 transitions), one for the rest."""
    table = np.full(256, 58, dtype=np.uint8)
    nxt = 0
    for code in range(256):
        bits = [(code >> i) & 1 for i in range(8)]
        if sum(bits[i] != bits[(i + 1) % 8] for i in range(8)) <= 2:
            table[code] = nxt
            nxt += 1
    return table


_LBP_TABLE = _uniform_lbp_table()
_OFFSETS = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))


def lbp_histogram(grey: np.ndarray) -> np.ndarray:
    """Uniform-LBP histogram (59 bins, sums to 1) of a grey uint8 image, vectorised over all pixels."""
    centre = grey[1:-1, 1:-1]
    h, w = grey.shape
    code = np.zeros(centre.shape, dtype=np.uint8)
    for bit, (dy, dx) in enumerate(_OFFSETS):
        neighbour = grey[1 + dy : h - 1 + dy, 1 + dx : w - 1 + dx]
        code |= (neighbour >= centre).astype(np.uint8) << bit
    hist = np.bincount(_LBP_TABLE[code].ravel(), minlength=59).astype(np.float64)
    return hist / max(hist.sum(), 1.0)


def hsv_histogram(bgr: np.ndarray) -> np.ndarray:
    """Joint HSV colour histogram (16 x 4 x 4 = 256 bins, sums to 1)."""
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    hist = cv2.calcHist([hsv], [0, 1, 2], None, list(HSV_BINS), [0, 180, 0, 256, 0, 256]).ravel()
    return hist.astype(np.float64) / max(float(hist.sum()), 1.0)


class VisualEncoder(Encoder):
    """Colour + texture + ORB-word histograms; no semantics (every frame scores 1.0)."""

    name = "visual"
    duplicate_cosine = 1e-6
    """Only the same pixels: measured on the survey video, this encoder's frames 1 s apart can be 4.6e-3 apart,
    less than a still's codec noise (5.6e-3), so no looser threshold tells a repeat from a slow drift."""

    def __init__(self, cfg: EncoderConfig | None = None) -> None:
        cfg = cfg or EncoderConfig(name="visual")
        w, h = DEFAULT_SIZE
        if cfg.input_size:
            scale = cfg.input_size / max(w, h)
            w, h = max(16, round(w * scale)), max(16, round(h * scale))
        self._size = (w, h)
        self._orb = cv2.ORB_create(nfeatures=ORB_FEATURES)
        rng = np.random.default_rng(VOCAB_SEED)
        self._vocab = np.unpackbits(rng.integers(0, 256, size=(ORB_WORDS, 32), dtype=np.uint8), axis=1)

    @property
    def input_size(self) -> tuple[int, int]:
        return self._size

    def orb_histogram(self, grey: np.ndarray) -> np.ndarray:
        """ORB descriptors quantised to the fixed vocabulary; uniform when the frame has no keypoints."""
        _, desc = self._orb.detectAndCompute(grey, None)
        if desc is None or len(desc) == 0:
            return np.full(ORB_WORDS, 1.0 / ORB_WORDS)
        bits = np.unpackbits(desc, axis=1)
        hamming = (bits[:, None, :] != self._vocab[None, :, :]).sum(axis=2)
        hist = np.bincount(hamming.argmin(axis=1), minlength=ORB_WORDS).astype(np.float64)
        return hist / hist.sum()

    def encode_one(self, bgr: np.ndarray) -> np.ndarray:
        if bgr.shape[1::-1] != self._size:
            bgr = cv2.resize(bgr, self._size, interpolation=cv2.INTER_AREA)
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        blocks = (hsv_histogram(bgr), lbp_histogram(grey), self.orb_histogram(grey))
        return (np.concatenate(blocks) / len(blocks)).astype(np.float32)

    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        if not images:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([self.encode_one(img) for img in images])

    @property
    def dim(self) -> int:
        return int(np.prod(HSV_BINS)) + 59 + ORB_WORDS

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """A placeholder (one zero per query): the baseline has no text tower and ignores the queries."""
        return np.zeros((len(texts), 1), dtype=np.float32)

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        """1.0 for every frame, so semantic pre-sampling passes everything (ROST has no semantic filter)."""
        return np.ones(len(image_embeddings), dtype=np.float32)

    def describe(self) -> dict:
        return {
            "name": self.name,
            "features": f"hsv {'x'.join(map(str, HSV_BINS))} + uniform lbp 59 + orb bag of {ORB_WORDS} words",
            "input_size": list(self._size),
            "semantic": "none: every frame scores 1.0 (ROST-style baseline)",
        }
