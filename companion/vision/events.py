"""What the vision side tells the rest: a frame entered or left the summary."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from vehicle.autopilot.pose import Pose


@dataclass
class SummaryFrame:
    """A frame that entered the summary, with everything the store and the surface link need."""

    image_index: int
    """Running index across restarts (the camera protocol's image_index; never reused)."""
    frame_index: int
    """0-based frame index in the source."""
    time_s: float
    """Seconds from the start of the source."""
    capture_time: float
    """Companion wall clock (seconds since epoch) at capture."""
    score: float
    """Semantic score ss_t (or ss_e after enhancement)."""
    image: np.ndarray
    """Full-resolution BGR frame (the enhanced one when enhancement ran)."""
    feature: np.ndarray
    """The sampler feature vector, kept so a restart resumes with the same summary."""
    pose: Pose | None = None
    raw_image: np.ndarray | None = None
    """The frame before enhancement, when enhancement ran."""
    enhanced: bool = False
    topic: str = ""
    """The name of the topic whose summary it entered (``queries.topics``; the default topic's name with one)."""
    below_threshold: bool = False
    """A stand-in: nothing passed tau_ss for a while, so the best frame seen is shown (``vision.below_threshold``)."""
    pilot: bool = False
    """Kept by the pilot's shutter (MAV_CMD_IMAGE_START_CAPTURE), whatever its score: never trimmed to make room
    (``companion.vision.pilot_capture``)."""
    raw_score: float | None = None
    """ss_t of the raw frame when ``score`` is the enhanced copy's ss_e (selective enhancement): the two gates it
    passed, side by side. None where the frame was not enhanced, or the encoder never saw it raw (``always``)."""


@dataclass
class SummaryEvent:
    """``added``: ``frame`` entered; ``removed``: ``frame`` was trimmed out. ``summary`` is the image indices now held."""

    kind: Literal["added", "removed"]
    frame: SummaryFrame
    summary: list[int] = field(default_factory=list)
