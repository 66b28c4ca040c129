"""The pilot's shutter: the current frame kept as the pilot's own summary frame, whatever its score.

QGroundControl shows a shutter button for a camera that says it captures images; the pilot presses it to keep
what is on screen, because the pilot judged it worth keeping, not the queries. Such a frame is scored like any
other (each topic's query, read against the dive like every frame's score, without joining it: one pressed frame
must not move the dive's mean) and filed
under the topic that scores it highest, but it stays outside that topic's informative sampler: the sampler never
trims it to make room, and it counts against no topic's K. It is numbered from the same running image indices,
stored, announced and served like every summary frame, and marked ``pilot``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.sources.frame import Frame
from companion.vision import distances as dist
from companion.vision.encoders.base import Encoder
from companion.vision.events import SummaryEvent, SummaryFrame
from companion.vision.image_indices import ImageIndices
from companion.vision.stand_in_stage import all_keys
from companion.vision.topics import Topic
from vehicle.autopilot.pose import Pose


def pilot_frame(encoder: Encoder, prepared: np.ndarray, topics: Sequence[Topic], frame: Frame,
                pose: Pose | None, index: int) -> tuple[SummaryFrame, Topic]:
    """``frame`` as the pilot's summary frame numbered ``index``, and the topic it is filed under (the first of
    the best-scoring ones); ``prepared`` is the copy the encoder sees."""
    emb = encoder.encode_images([prepared])
    scores = [float(t.presampler.scores(emb, join=False)[0]) for t in topics]  # judged in the dive, not joining it
    best = int(np.argmax(scores))
    feature = dist.prepare_features(encoder.sampler_features(emb))[0]
    held = SummaryFrame(image_index=index, frame_index=frame.index, time_s=frame.time_s,
                        capture_time=frame.capture_time, score=scores[best], image=frame.image,
                        feature=np.array(feature, copy=True), pose=pose, topic=topics[best].name, pilot=True)
    return held, topics[best]


def take_pilot_frame(encoder: Encoder, prepared: np.ndarray, topics: Sequence[Topic], indices: ImageIndices,
                     frame: Frame, pose: Pose | None) -> list[SummaryEvent]:
    """Keep ``frame`` as the pilot's: its "added" event ([] when every image index is used up)."""
    if not indices.left():
        return []
    held, topic = pilot_frame(encoder, prepared, topics, frame, pose, indices.next)
    indices.take()
    topic.held[held.image_index] = held
    topic.pilot.append(held.image_index)
    return [SummaryEvent("added", held, all_keys(topics))]


def refile_pilot_frames(dropped: Sequence[Topic], into: Topic) -> None:
    """The pilot's frames of topics no longer followed go to ``into``: a topic switch never loses them."""
    for topic in dropped:
        for key in topic.pilot:
            frame = topic.held[key]
            frame.topic = into.name
            into.held[key] = frame
            into.pilot.append(key)
        topic.pilot.clear()
