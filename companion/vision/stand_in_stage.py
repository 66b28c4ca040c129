"""The pipeline's last stage for a topic nothing has passed: its best frames stand in (``below_threshold``).

Per batch and topic: a pass ends the quiet period (its stand-ins leave the summary); else, while the topic's
summary is empty, the batch's best frame may become a stand-in, and the stand-ins enter once the quiet period is
long enough (``quiet_s`` seconds of footage), or at the end of the footage (``finish_events``). Stand-ins are
numbered from the same image indices as every summary frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.sources.frame import Frame
from companion.vision import distances as dist
from companion.vision.below_threshold import KEEP, stand_in
from companion.vision.events import SummaryEvent
from companion.vision.frame_result import FrameResult, raw_behind
from companion.vision.image_indices import ImageIndices
from companion.vision.topics import Topic
from vehicle.autopilot.pose import Pose


def all_keys(topics: Sequence[Topic]) -> list[int]:
    """Every image index the summaries hold now, topic by topic."""
    return [key for topic in topics for key in topic.keys]


def stand_in_events(topics: Sequence[Topic], indices: ImageIndices, frames: Sequence[Frame],
                    results: Sequence[FrameResult], pooled: np.ndarray, passed: np.ndarray, scores: np.ndarray,
                    images: Sequence[np.ndarray], poses: Sequence[Pose | None] | None, enhance_mode: str,
                    quiet_s: float) -> list[SummaryEvent]:
    """The summary events of one batch's stand-ins (``passed`` and ``scores``: frames x topics)."""
    events: list[SummaryEvent] = []
    for t, topic in enumerate(topics):
        below = topic.below
        below.seen(frames[0].time_s)
        hits = np.flatnonzero(passed[:, t])
        if len(hits):
            gone = below.passed(frames[hits[-1]].time_s)
            keys = all_keys(topics)
            events.extend(SummaryEvent("removed", f, list(keys)) for f in gone)
            continue
        if topic.sampler.keys:
            continue
        below.keep = min(KEEP, topic.sampler.k)
        i = int(np.argmax(scores[:, t]))
        below.consider(stand_in(frames[i], images[i], float(scores[i, t]), dist.prepare_features(pooled[i:i + 1])[0],
                                poses[i] if poses is not None else None, topic.name,
                                raw=raw_behind(frames[i], images[i], results[i], topic.name, enhance_mode)))
        if below.due(frames[-1].time_s, quiet_s):
            events.extend(show_stand_ins(topics, topic, indices))
    return events


def show_stand_ins(topics: Sequence[Topic], topic: Topic, indices: ImageIndices) -> list[SummaryEvent]:
    """Make the summary show exactly the topic's current candidates (numbering the new ones)."""
    add, gone = topic.below.to_show()
    events = [SummaryEvent("removed", f, all_keys(topics)) for f in gone]
    for frame in sorted(add, key=lambda f: f.time_s):
        if not indices.left():
            break
        frame.image_index = indices.take()
        topic.below.showing(frame)
        events.append(SummaryEvent("added", frame, all_keys(topics)))
    return events


def finish_events(topics: Sequence[Topic], indices: ImageIndices) -> list[SummaryEvent]:
    """End of the footage: an empty topic shows its best frames now, however short the quiet period was."""
    events: list[SummaryEvent] = []
    for topic in topics:
        if not topic.sampler.keys and topic.below.candidates:
            events.extend(show_stand_ins(topics, topic, indices))
    return events
