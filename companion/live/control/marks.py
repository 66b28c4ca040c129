"""The operator's marks (image indices liked or unliked on the surface): applied per topic, saved, restored."""

from __future__ import annotations

import logging

import numpy as np

from companion.live.control.context import ControlContext
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.vision.feedback import MarkedPreSampler, Marks

log = logging.getLogger(__name__)


class MarksHandler:
    """``Downlink.on_marks_changed``'s callback, and the marks an earlier run saved, re-applied at start."""

    def __init__(self, ctx: ControlContext, file: MarksFile) -> None:
        self.ctx = ctx
        self.file = file
        self.marks = SavedMarks()
        """The marks in force (image indices), and the queries they were given under."""
        self.images = 0
        """Marked frames the encoder embedded (beside the frames it scored)."""

    def __call__(self, like: list[int], unlike: list[int]) -> None:
        """Marks from the surface: score by them from the next batch on, and keep them on disk.

        ValueError (a frame the store no longer has) refuses the upload; the surface gets a NAK.
        """
        self.marks = self.ctx.keeper.submit(lambda: self._apply_and_state(like, unlike), lambda _marks: [])
        if self.ctx.surface is not None:
            self.ctx.surface.set_marks(like, unlike)
        try:
            if self.marks:
                self.file.save(self.marks)
            else:
                self.file.clear()
        except OSError as err:  # a memory-only store: the marks hold for this run
            log.warning("marks not saved: %s", err)
        log.info("marks set: like %s, unlike %s", like, unlike)

    def _apply_and_state(self, like: list[int], unlike: list[int]) -> SavedMarks:
        """Inside the keeper: apply, then read the queries they were given under in the same change."""
        self._apply(like, unlike)
        pipeline = self.ctx.pipeline
        return SavedMarks(list(like), list(unlike), pipeline.presampler.positive,
                          {t.name: t.presampler.positive for t in pipeline.topics})

    def restore(self, saved: SavedMarks) -> None:
        """Re-apply the marks an earlier run saved, each only if its topic's query is still the one in force."""
        if not saved:
            return
        queries = {t.name: t.presampler.positive for t in self.ctx.pipeline.topics}

        def current(indices: list[int]) -> list[int]:
            kept = []
            for index in indices:
                topic = self._topic_of(index)
                if topic is None or saved.query_of(topic) == queries.get(topic):
                    kept.append(index)  # (a frame the store lacks: refused below, naming it)
                else:
                    log.info("saved marks were given for %r, not %r: not applied to image %d (topic %s)",
                             saved.query_of(topic), queries.get(topic), index, topic)
            return kept

        like, unlike = current(saved.like), current(saved.unlike)
        if not like and not unlike:
            return
        try:
            self.ctx.keeper.submit(lambda: self._apply(like, unlike))
        except ValueError as err:
            log.warning("saved marks not applied: %s", err)
            return
        self.marks = SavedMarks(like, unlike, saved.query, {t: q for t, q in saved.topics.items() if t in queries})
        log.info("restored marks: %d like, %d unlike", len(like), len(unlike))

    def _topic_of(self, index: int) -> str | None:
        """The topic a summary frame belongs to: the one holding it, else its sidecar's (a frame stored before
        topics: the default topic, ``queries.name``); None when the store does not have it."""
        held = self.ctx.pipeline.topic_of(index)
        if held is not None:
            return held.name
        sidecar = self.ctx.store.sidecar(index)
        if sidecar is None:
            return None
        return str(sidecar.get("topic") or self.ctx.pipeline.untagged_topic())

    def _apply(self, like: list[int], unlike: list[int]) -> None:
        """Embed the marked frames' stored images (as captured, where kept) and switch each topic's pre-sampler(s)
        to the combined score.

        A mark teaches the topic of the frame it names (marking a coral frame says nothing about fish), so each
        topic gets only its own marks, and a topic with none scores by its queries alone. Runs inside the
        keeper: the encoder is the inference loop's, and the next batch sees the new scores.
        """
        ctx = self.ctx
        pipeline = ctx.pipeline

        scores: dict[str, tuple[list[float], list[float]]] = {t.name: ([], []) for t in pipeline.topics}

        def images(indices: list[int], side: int) -> dict[str, list]:
            found: dict[str, list] = {t.name: [] for t in pipeline.topics}
            for index in indices:
                frame = ctx.store.frame(index)
                if frame is None or frame.image is None:
                    raise ValueError(f"image {index} is not in the store")
                topic = self._topic_of(index)
                if topic not in found:
                    raise ValueError(f"image {index} is of topic {topic}, no longer followed")
                # the frame as captured where the store has it (held frames; from disk with store.keep_raw): the
                # marks are compared with raw frames in the raw dive (a copy is judged by its raw frame's row)
                found[topic].append(pipeline.prepare(frame.image if frame.raw_image is None else frame.raw_image))
                # the score it was kept with, in its dive: what the marks' doubt of the query is measured on
                scores[topic][side].append(frame.score if frame.raw_score is None else frame.raw_score)
            return found

        liked, unliked = images(like, 0), images(unlike, 1)  # all checked before any topic changes
        for topic in pipeline.topics:
            if liked[topic.name] or unliked[topic.name]:
                marks = Marks.from_images(ctx.encoder, liked[topic.name], unliked[topic.name],
                                          topic.presampler.text_embeddings, scores[topic.name])
                self.images += len(liked[topic.name]) + len(unliked[topic.name])
            else:
                marks = Marks(np.zeros((0, 1)), np.zeros((0, 1)))
            topic.presampler = marked(topic.presampler, marks)
            if ctx.selective is not None:
                raw = ctx.selective.raw.presamplers
                raw[topic.name] = marked(raw[topic.name], marks)


def marked(presampler, marks: Marks):
    """``presampler`` scoring with ``marks`` (wrapped once; later marks, or none, replace the examples)."""
    if isinstance(presampler, MarkedPreSampler):
        presampler.set_marks(marks)
        return presampler
    return MarkedPreSampler(presampler, marks) if len(marks) else presampler
