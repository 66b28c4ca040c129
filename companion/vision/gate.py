"""The frame gate: decide, before the encoder, which frames are worth encoding at all.

The encoder is nearly all of the pipeline's cost, and an ROV drifting over a reef hands it long runs of
near-identical frames that cannot change the summary. The gate compares a tiny grey copy of each frame (32x18 by
default, a few microseconds to make) with the copy of the last frame it let through, by mean absolute difference
in grey levels (0-255). A frame that differs by more than ``threshold`` is encoded; so is any frame more than
``max_gap_s`` seconds (of source time) after the last encoded one, so a slow drift is still sampled, and any frame
whose time goes backwards (a looped file, a restarted camera). A skipped frame counts as seen and inherits nothing
into the summary: it is neither scored nor offered to the sampler (the cheap difference detector of video
analytics systems such as NoScope).

Time alone cannot know how long the footage will be: a 1-s clip gated at one frame per 0.5 s gives the sampler two
frames to choose from, and its summary loses the spread the ungated one has. So a frame is also encoded once
``max_gap_share`` of the frames seen so far have passed since the last encoded one (0.05: the first twenty frames
all, then ever sparser). Whatever the footage's length, every twentieth of it so far holds an encoded frame; it costs
a few dozen calls at the start of a dive, and after that the time rule fires first. It is online: it counts only frames
already seen.
"""

from __future__ import annotations

import cv2
import numpy as np

GATE_MODES = ("none", "difference")
TINY_SIZE = (32, 18)
"""(width, height) of the copies compared: 16:9 like most cameras, big enough to see a fish cross the frame."""


def tiny_grey(image: np.ndarray, size: tuple[int, int] = TINY_SIZE) -> np.ndarray:
    """The gate's view of a frame: area-averaged to ``size`` (w, h), grey, float32."""
    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    if small.ndim == 3:
        small = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
    return small.astype(np.float32)


class FrameGate:
    """Remembers the last encoded frame's tiny copy and when it came; ``admit`` says whether the next frame is encoded.

    ``mode`` ``none`` admits every frame (the ungated pipeline). ``threshold`` and ``mode`` may be changed
    between calls (live tuning); a change takes effect with the next frame.
    """

    def __init__(self, mode: str = "difference", threshold: float = 8.0, max_gap_s: float = 0.5,
                 max_gap_share: float = 0.05, *, size: tuple[int, int] = TINY_SIZE) -> None:
        if mode not in GATE_MODES:
            raise ValueError(f"gate.mode: {mode!r} is not one of {', '.join(GATE_MODES)}")
        if threshold < 0:
            raise ValueError(f"gate.threshold: must be 0 or more, got {threshold}")
        if max_gap_s <= 0:
            raise ValueError(f"gate.max_gap_s: must be more than 0, got {max_gap_s}")
        if not 0 <= max_gap_share < 1:
            raise ValueError(f"gate.max_gap_share: must be in [0, 1), got {max_gap_share}")
        self.mode = mode
        self.threshold = float(threshold)
        self.max_gap_s = float(max_gap_s)
        self.max_gap_share = float(max_gap_share)
        self.size = size
        self.seen = 0
        self.encoded = 0
        self.last_difference: float | None = None
        """Mean absolute difference of the last frame looked at against the reference (None: no reference)."""
        self._reference: np.ndarray | None = None
        self._reference_time: float | None = None
        self._reference_seen = 0

    @property
    def on(self) -> bool:
        return self.mode != "none"

    @property
    def skipped(self) -> int:
        return self.seen - self.encoded

    def reset(self) -> None:
        """Forget the reference: the next frame is encoded (e.g. the queries changed)."""
        self._reference = None
        self._reference_time = None

    def admit(self, image: np.ndarray, time_s: float) -> bool:
        """True when the frame must be encoded; it then becomes the reference the next frames are compared with."""
        self.seen += 1
        if not self.on:
            self.encoded += 1
            return True
        tiny = tiny_grey(image, self.size)
        ref, ref_time = self._reference, self._reference_time
        if ref is None or ref_time is None or ref.shape != tiny.shape:
            self.last_difference = None
            go = True
        else:
            self.last_difference = float(np.abs(tiny - ref).mean())
            gap = time_s - ref_time
            go = (self.last_difference > self.threshold or gap >= self.max_gap_s or gap < 0
                  or self._share_due())
        if go:
            self._reference, self._reference_time, self._reference_seen = tiny, float(time_s), self.seen
            self.encoded += 1
        return go

    def _share_due(self) -> bool:
        """More than ``max_gap_share`` of the frames seen so far have passed since the last encoded one."""
        return self.max_gap_share > 0 and self.seen - self._reference_seen >= self.max_gap_share * self.seen

    def admit_batch(self, images: list[np.ndarray], times: list[float]) -> np.ndarray:
        """``admit`` for each frame in order; a boolean mask."""
        return np.array([self.admit(img, t) for img, t in zip(images, times, strict=True)], dtype=bool)
