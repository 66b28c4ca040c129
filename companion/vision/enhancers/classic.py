"""The default enhancer: a fast, weight-free fix for underwater haze and colour cast.

Three well-known steps, in the order the physics suggests (remove the scattered veil first, then balance the
colour that is left, then stretch local contrast):

1. Dehaze with the underwater dark channel prior (UDCP, Drews et al. 2013: the dark channel of green and blue
   only, since red is absorbed and would make every pixel look hazy). The transmission map is estimated at a
   reduced resolution (longest side ``work_side``), refined with He et al.'s guided filter (built from
   ``cv2.boxFilter``, vectorised) and scaled back up, so its cost hardly grows with the frame size.
2. White balance: gray-world (scale each channel to the common mean) or white-patch (scale each channel's
   99th percentile to white), with the gains clipped so a nearly absent red channel is not turned into noise.
3. CLAHE on the luminance (L of CIE L*a*b*), which lifts local contrast without shifting the colours again.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from companion.vision.enhancers.base import Enhancer


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """He, Sun, Tang (2013) guided filter with a gray guide: edge-preserving smoothing of ``src`` along ``guide``.

    Both float32 in [0, 1], same shape; every mean is one ``cv2.boxFilter`` pass.
    """
    size = (2 * radius + 1, 2 * radius + 1)

    def box(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, -1, size, borderType=cv2.BORDER_REFLECT)

    mean_i = box(guide)
    mean_p = box(src)
    var_i = box(guide * guide) - mean_i * mean_i
    cov_ip = box(guide * src) - mean_i * mean_p
    a = cov_ip / (var_i + eps)
    b = mean_p - a * mean_i
    return box(a) * guide + box(b)


class ClassicEnhancer(Enhancer):
    """UDCP dehaze + white balance + CLAHE; see the module docstring for why each step is there."""

    name = "classic"

    def __init__(
        self,
        *,
        white_balance: Literal["gray-world", "white-patch"] = "gray-world",
        dehaze_strength: float = 0.6,
        min_transmission: float = 0.25,
        clahe_clip: float = 1.5,
        clahe_tiles: int = 8,
        work_side: int = 160,
        max_gain: float = 1.6,
    ) -> None:
        if white_balance not in ("gray-world", "white-patch"):
            raise ValueError(f"white_balance must be gray-world or white-patch, got {white_balance!r}")
        self.white_balance = white_balance
        self.dehaze_strength = dehaze_strength
        self.min_transmission = min_transmission
        self.clahe_clip = clahe_clip
        self.clahe_tiles = clahe_tiles
        self.work_side = work_side
        self.max_gain = max_gain
        self._clahe = cv2.createCLAHE(clipLimit=clahe_clip, tileGridSize=(clahe_tiles, clahe_tiles))

    def describe(self) -> dict:
        return {
            "name": self.name,
            "white_balance": self.white_balance,
            "dehaze_strength": self.dehaze_strength,
            "min_transmission": self.min_transmission,
            "clahe_clip": self.clahe_clip,
            "work_side": self.work_side,
        }

    def enhance(self, image: np.ndarray) -> np.ndarray:
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"expected a BGR uint8 HxWx3 image, got {image.dtype} {image.shape}")
        h, w = image.shape[:2]
        scale = min(1.0, self.work_side / max(h, w))
        small = image if scale == 1.0 else cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))),
                                                      interpolation=cv2.INTER_AREA)
        veil, t = self._transmission(small.astype(np.float32) * (1.0 / 255.0))
        if scale != 1.0:
            t = cv2.resize(t, (w, h), interpolation=cv2.INTER_LINEAR)
        inv_t = 1.0 / np.maximum(t, self.min_transmission)
        # Scene recovery J = (I - veil) / t + veil, in place on one float buffer (0-255 units).
        veil255 = veil * 255.0
        j = image.astype(np.float32)
        j -= veil255
        j *= inv_t[..., None]
        j += veil255
        np.clip(j, 0.0, 255.0, out=j)
        j *= self._gains(j)
        out = cv2.convertScaleAbs(j)  # rounds and saturates to uint8 (j >= 0, so abs changes nothing)
        lab = cv2.cvtColor(out, cv2.COLOR_BGR2LAB)
        lab[..., 0] = self._clahe.apply(np.ascontiguousarray(lab[..., 0]))
        return cv2.cvtColor(lab, cv2.COLOR_LAB2BGR)

    def _transmission(self, small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Veil colour (BGR in 0-1) and the refined transmission map at the reduced resolution."""
        patch = max(3, int(round(15 * max(small.shape[:2]) / 480)) | 1)
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (patch, patch))
        # Underwater dark channel: green and blue only.
        dark = cv2.erode(np.minimum(small[..., 0], small[..., 1]), kernel)
        # Veil (background light): mean colour of the 0.1% haziest pixels.
        flat = dark.ravel()
        n = max(1, flat.size // 1000)
        idx = np.argpartition(flat, flat.size - n)[-n:]
        veil = np.maximum(small.reshape(-1, 3)[idx].mean(axis=0), 0.05).astype(np.float32)
        normed = np.minimum(small[..., 0] / veil[0], small[..., 1] / veil[1])
        t = 1.0 - self.dehaze_strength * cv2.erode(normed, kernel)
        guide = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
        t = guided_filter(guide, t.astype(np.float32), radius=max(2, 2 * patch), eps=1e-3)
        return veil, t

    def _gains(self, img: np.ndarray) -> np.ndarray:
        """Per-channel white-balance gains for a BGR float image in 0-255, clipped to [1/max_gain, max_gain]."""
        if self.white_balance == "gray-world":
            means = np.array(cv2.mean(img)[:3])
            gains = means.mean() / np.maximum(means, 0.255)
        else:
            step = max(1, img.size // 3 // 20000)
            tops = np.percentile(img.reshape(-1, 3)[::step], 99, axis=0)
            gains = 255.0 / np.maximum(tops, 0.255)
        return np.clip(gains, 1.0 / self.max_gain, self.max_gain).astype(np.float32)
