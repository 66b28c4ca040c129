"""What is new in a frame's pixels against its dive so far: a few numbers on the brightest compact change.

The scene residual on the network's features (``scene_memory``) looks through 32-pixel cells, and a fish a few
pixels wide in green haze (DeepFish habitat 7393) is lost in them: it stays ranked below chance. In the pixels
the same fish stands out plainly against the dive's background, the way a fixed camera's motion detector sees
it. So each frame, at 112x64 (a quarter of the encoder's 448x256 input), is compared with the dive's causal
running mean of the frames before it (``RunningMean.take``: a frame is not its own background), plain up to
``tau`` frames and exponential after, and gives 12 numbers: the largest, 99th-percentile and mean absolute
change, and the largest "blob" contrast (a box mean of the change minus that of a box five times wider, so a
swaying root or a whole-frame shift counts less than a compact spot) at three sizes; then the same six on the change divided by
the dive's running spread (the square root of the running mean squared change, this frame's included, plus its
mean over the frame: a spot where the scene is usually still counts more). They are appended to the scene
residual and read by the same scene head, which learns from the data how far to trust them (a moving ROV
changes every pixel, a fixed camera few). Measured held out on the shared data: docs/encoders.md.

A portrait frame in a landscape dive is compared turned, against a background of landscape frames: its changes
say little (as its view features do), which a dive of one camera does not meet.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.vision.running_mean import TAU, RunningMean

SIZE = (112, 64)
"""(width, height) of the small frame compared with the dive's background (landscape; portrait frames turned)."""
CHANNELS = 3
PIXELS = SIZE[0] * SIZE[1] * CHANNELS
"""Floats a small frame takes in an embedding row."""
FEATURES = 12
"""Numbers per frame: six on the plain change, six on the change over the dive's spread."""
BLUR = 0.7
"""Gaussian sigma (small-frame pixels) against JPEG and sensor noise before comparing."""
BLOBS = (3, 5, 9)
"""Box sizes (small-frame pixels) of the compact-change measure; the surround is five times as wide. A fish 8 to
48 pixels long in a 360-pixel frame is 2.5 to 15 here."""
GAIN = 10.0
"""Features are log(1 + GAIN x value): the changes span orders of magnitude between still and moving cameras."""


def small_frame(image: np.ndarray) -> np.ndarray:
    """(64, 112, 3) float32 in [0, 1] of a BGR frame as the encoder resized it (portrait frames turned)."""
    if image.shape[0] > image.shape[1]:
        image = np.ascontiguousarray(np.rot90(image))
    small = cv2.resize(image, SIZE, interpolation=cv2.INTER_AREA)
    return small.astype(np.float32) / 255.0


def _blob(change: np.ndarray, box: int) -> float:
    return float((cv2.blur(change, (box, box)) - cv2.blur(change, (5 * box, 5 * box))).max())


def change_features(change: np.ndarray) -> list[float]:
    """Six numbers on one (H, W) change map: max, 99th percentile, mean, and the compact-change contrasts."""
    return [float(change.max()), float(np.quantile(change, 0.99)), float(change.mean()),
            *(_blob(change, b) for b in BLOBS)]


class PixelScene:
    """One dive's running mean and spread of its small frames, and each frame's change features against them."""

    def __init__(self, tau: float = TAU) -> None:
        self.tau = tau
        self._mean: RunningMean | None = None
        self._square: RunningMean | None = None

    @property
    def seen(self) -> bool:
        return self._mean is not None

    def features(self, pixels: np.ndarray, *, join: bool = True) -> np.ndarray:
        """(N, 64, 112, 3) small frames in order -> (N, 12), NaN for a frame with no scene before it.

        ``join``: each frame is compared with the mean of the frames before it, then taken into the mean, and its
        squared change into the spread it is divided by; without it (a frame scored again, e.g. its enhanced copy)
        the mean and spread are used as they stand and kept.
        """
        p = np.asarray(pixels, dtype=np.float64)
        if p.ndim != 4 or p.shape[1:] != (SIZE[1], SIZE[0], CHANNELS):
            raise ValueError(f"pixels must be (frames, {SIZE[1]}, {SIZE[0]}, {CHANNELS}), got shape {p.shape}")
        out = np.full((len(p), FEATURES), np.nan)
        for i, frame in enumerate(p):
            x = cv2.GaussianBlur(frame, (0, 0), BLUR)
            if self._mean is None or self._square is None:
                if join:
                    self._mean = RunningMean(x, 0.0, self.tau)
                    self._mean.centre(x)
                    self._square = RunningMean(np.zeros_like(x), 0.0, self.tau)
                    self._square.centre(np.zeros_like(x))
                continue  # nothing to compare with
            if join:
                diff = self._mean.take(x)
                self._square.centre(diff ** 2)
            else:
                diff = x - self._mean.mean
            change = np.abs(diff).sum(axis=2).astype(np.float32)
            spread = self._square.mean.sum(axis=2)
            scaled = (change / np.sqrt(spread + max(float(spread.mean()), 1e-4))).astype(np.float32)
            out[i] = np.log1p(GAIN * np.array(change_features(change) + change_features(scaled)))
        return out
