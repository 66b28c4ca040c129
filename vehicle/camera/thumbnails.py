"""Thumbnails that fit a byte budget: the surface link is a few kB/s, so every thumbnail has a hard size cap.

Search quality first (binary search for the best quality that fits at the preferred size), and only when even
the lowest useful quality does not fit, shrink the image (keeping its aspect ratio) and search again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

Format = Literal["jpeg", "webp"]
MIN_QUALITY = 5
MAX_QUALITY = 95
MIN_SIDE = 16


@dataclass(frozen=True)
class Thumbnail:
    """Encoded bytes and how they were made (the image push handshake carries width, height and quality)."""

    data: bytes
    format: Format
    width: int
    height: int
    quality: int


def _encode(image: np.ndarray, fmt: Format, quality: int) -> bytes:
    if fmt == "jpeg":
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_OPTIMIZE, 1])
    else:
        ok, buf = cv2.imencode(".webp", image, [cv2.IMWRITE_WEBP_QUALITY, quality])
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.shape} image as {fmt}")
    return buf.tobytes()


def fit_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """The size with the longer side at most ``max_side``, aspect ratio kept (never upscaled)."""
    scale = min(1.0, max_side / max(width, height))
    return max(1, round(width * scale)), max(1, round(height * scale))


def make_thumbnail(image: np.ndarray, max_bytes: int = 2500, *, max_side: int = 160,
                   fmt: Format = "jpeg") -> Thumbnail:
    """Encode ``image`` (BGR uint8) to at most ``max_bytes``, as large and as good as the budget allows."""
    if image is None or image.ndim not in (2, 3) or image.size == 0:
        raise ValueError("thumbnail source must be a non-empty BGR or grey image")
    h, w = image.shape[:2]
    side = max_side
    while True:
        tw, th = fit_size(w, h, side)
        small = cv2.resize(image, (tw, th), interpolation=cv2.INTER_AREA) if (tw, th) != (w, h) else image
        best: tuple[int, bytes] | None = None
        lo, hi = MIN_QUALITY, MAX_QUALITY
        while lo <= hi:
            mid = (lo + hi) // 2
            data = _encode(small, fmt, mid)
            if len(data) <= max_bytes:
                best = (mid, data)
                lo = mid + 1
            else:
                hi = mid - 1
        if best is not None:
            return Thumbnail(best[1], fmt, tw, th, best[0])
        if max(tw, th) <= MIN_SIDE:
            raise ValueError(f"cannot fit a thumbnail into {max_bytes} bytes even at {tw}x{th}")
        side = max(MIN_SIDE, int(max(tw, th) * 0.8))
