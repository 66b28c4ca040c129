"""The frame as it travels from a source through the pipeline."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One decoded frame and where it came from.

    ``index`` and ``time_s`` locate the frame in its source (so a summary can be traced back to the video);
    ``capture_time`` is the companion's wall clock (``time.time()``) at capture, the key for the pose lookup.
    """

    image: np.ndarray
    """BGR, uint8, H x W x 3 (OpenCV's convention)."""
    index: int
    """0-based frame index in the source, before subsampling."""
    time_s: float
    """Seconds from the start of the source."""
    capture_time: float
    """Companion wall-clock time (seconds since the epoch) when the frame was captured."""
    captured: Captured | None = None
    """When ``image`` is an enhanced copy made outside the pipeline (the live enhance worker): the frame as the
    camera gave it, and its ss_t per topic, which the summary keeps beside the copy."""


@dataclass(frozen=True)
class Captured:
    """A frame as captured, behind its enhanced copy: its pixels and its scores (ss_t) by topic name."""

    image: np.ndarray
    scores: dict[str, float]
