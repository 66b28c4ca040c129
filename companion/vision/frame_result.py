"""What the pipeline says of each frame of a batch, and the raw frame behind an enhanced summary image."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.sources.frame import Frame
from companion.vision.events import SummaryEvent


@dataclass
class FrameResult:
    """What happened to one frame."""

    frame_index: int
    time_s: float
    score: float
    """ss_t of the frame the encoder saw first (the enhanced one in mode ``always``); with several topics the
    highest of their scores (``topic_scores`` has each)."""
    passed: bool
    """ss_t > tau_ss (for at least one topic)."""
    enhanced: bool = False
    """An enhanced version was made and scored."""
    enhanced_score: float | None = None
    """ss_e, when ``enhanced`` (selective mode)."""
    offered: bool = False
    """It reached the sampler."""
    added: bool = False
    """It entered the summary."""
    image_index: int | None = None
    encoded: bool = True
    """False: the frame gate skipped it (score is NaN, it passed nothing)."""
    topic_scores: dict[str, float] = field(default_factory=dict)
    """ss_t per topic, by name (empty when the gate skipped the frame)."""
    added_to: list[str] = field(default_factory=list)
    """The topics whose summary it entered."""


@dataclass
class BatchOutcome:
    results: list[FrameResult]
    events: list[SummaryEvent]



def raw_behind(frame: Frame, image: np.ndarray, result: FrameResult, topic: str,
               enhance_mode: str) -> tuple[np.ndarray | None, float | None]:
    """The raw frame behind a summary image that is an enhanced copy, and its ss_t for the topic (None where the
    encoder never saw it raw: mode ``always``); (None, None) for a frame shown as captured."""
    if frame.captured is not None:  # enhanced by the live worker, scored raw by its raw gate
        return frame.captured.image, frame.captured.scores.get(topic)
    if image is frame.image:
        return None, None
    return frame.image, result.topic_scores.get(topic) if enhance_mode == "selective" else None


