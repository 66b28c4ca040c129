"""The one writer of the summary and its store: every change goes through here, in order.

Three threads change what the companion keeps: the inference loop (new frames and the trims they cause), the
enhancer worker (enhanced frames) and the surface link (K, tau_ss, queries, enhancement on or off). Applying the
sampler's events to the store outside the lock that guarded the sampler let two threads interleave: a stale
event's summary list could overwrite a newer one, leaving "ghost" frames on disk that the sampler no longer held,
or missing ones it did. The keeper owns the pipeline's summary and the store together: a caller hands it a
change (a function that touches the pipeline and returns the summary events it caused) and waits; the keeper
runs it and applies its events to the store, then to the surface, before the next change may start. So after
every change the store on disk equals the sampler's summary.

The keeper runs the change on the caller's thread under its lock rather than on a thread of its own: the
ordering is the same, and the inference loop, which makes most changes, pays no hand-over.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame

log = logging.getLogger(__name__)

T = TypeVar("T")
HISTORY = 128
"""How many recent (events applied, summary) pairs ``document`` shows, for audits from the surface."""


class SummaryKeeper:
    """Owns ``pipeline``'s summary and ``store``; ``change(fn)`` is the only way to alter either."""

    def __init__(self, pipeline: Any, store: Store, *, tags: Callable[[SummaryFrame], dict[str, Any]],
                 publish: Callable[[SummaryEvent], None] | None = None) -> None:
        self.pipeline = pipeline
        self.store = store
        self.tags = tags
        """Tags of a new frame at the moment it is stored (its topic's live query, the encoder, the source)."""
        self.publish = publish
        """Announces an event to the surface; never allowed to stop the summary being kept."""
        self.lock = threading.RLock()
        """Held for the whole of a change; the selective stage shares it to serialise the encoder."""
        self.applied = 0
        self.mismatches = 0
        """Changes after which the store's summary differed from the sampler's (a bug if ever above 0)."""
        self._history: deque[tuple[int, list[int]]] = deque(maxlen=HISTORY)
        self._by_topic: dict[str, int] = {}

    def change(self, fn: Callable[[], T], events_of: Callable[[T], list[SummaryEvent]] | None = None) -> T:
        """Run ``fn`` (which may alter the pipeline) and apply the events it caused; returns what ``fn`` did.

        ``events_of`` extracts the events from ``fn``'s result (default: the result is the event list, or None).
        """
        with self.lock:
            result = fn()
            events = events_of(result) if events_of is not None else (result or [])
            if events:
                self._apply(events)
            # replaced whole, never changed in place: the status thread reads it without the lock
            self._by_topic = {t.name: len(t.sampler.keys) for t in getattr(self.pipeline, "topics", [])}
            return result

    def held_by_topic(self) -> dict[str, int]:
        """How many frames each topic's summary held after the last change (for the status line, lock-free)."""
        return self._by_topic

    def _apply(self, events: list[SummaryEvent]) -> None:
        """Store first (the source of truth), then the surface: a crash in between loses no saved frame."""
        for event in events:
            self.store.apply(event, tags=self.tags(event.frame) if event.kind == "added" else None)
            self.applied += 1
            if self.publish is not None:
                try:
                    self.publish(event)
                except Exception:  # noqa: BLE001 - the surface link must never stop the summary being kept
                    log.exception("surface link could not publish image %d", event.frame.image_index)
        held = self.held()
        if self.store.summary != held:
            self.mismatches += 1
            log.error("store summary %s differs from the sampler's %s", self.store.summary, held)
        self._history.append((self.applied, held))

    def held(self) -> list[int]:
        """The image indices the sampler holds now, in the order they entered."""
        return [f.image_index for f in self.pipeline.summary]

    def republish(self) -> None:
        """Announce every held frame again (after the surface link starts on a resumed summary)."""
        if self.publish is None:
            return
        with self.lock:
            frames = self.pipeline.summary
            keys = [f.image_index for f in frames]
            for frame in frames:
                self.publish(SummaryEvent("added", frame, keys))

    def document(self) -> dict[str, Any]:
        """What the keeper holds, for /store/summary.json: the summary now and after each recent change.

        ``history`` pairs the count of events applied to the store (this run) with the sampler's summary right
        after them, so a client can check the store's change log line by line against it.
        """
        with self.lock:
            return {"summary": self.held(), "applied": self.applied,
                    "next_image_index": self.pipeline.next_image_index, "store": self.store.summary,
                    "mismatches": self.mismatches,
                    "history": [[n, list(s)] for n, s in self._history], "time": time.time()}
