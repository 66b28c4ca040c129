"""What the on-board camera server needs to know of a summary frame, as a structural type.

The app's own summary frame (``companion.vision.events.SummaryFrame``) has these attributes and more; the camera
side reads only these, so ``vehicle/`` never imports the app and the app never converts its frames.
"""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np

from vehicle.autopilot.pose import Pose

MAX_IMAGE_INDEX = 2**31 - 1
"""The highest image index there can be: CAMERA_IMAGE_CAPTURED carries ``image_index`` as an int32 (pymavlink
refuses to pack a higher one). Whoever numbers frames stops there; there is no wrap, which would hand out an
index clients already hold."""


class CaptureFrame(Protocol):
    """A frame to announce, push and serve: its running index, when it was taken, its score, pose and pixels."""

    image_index: int
    frame_index: int
    time_s: float
    capture_time: float
    score: float
    image: np.ndarray
    pose: Pose | None
    raw_image: np.ndarray | None
    enhanced: bool
    topic: str
    """The topic whose summary holds it (several may be followed at once; one name with one topic)."""
    raw_score: float | None
    """The raw frame's score when ``score`` is its enhanced copy's; else None."""


class CaptureEvent(Protocol):
    """``added``: ``frame`` entered the summary; ``removed``: it was trimmed out. ``summary``: indices now held."""

    kind: Literal["added", "removed"]
    frame: CaptureFrame
    summary: list[int]
