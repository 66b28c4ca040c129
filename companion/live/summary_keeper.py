"""The one writer of the summary and its store: every change goes through here, in order.

Three threads change what the companion keeps: the inference loop (new frames and the trims they cause), the
enhancer worker (enhanced frames) and the keeper's own thread (what the surface asks: K, tau_ss, queries, marks,
enhancement on or off). Applying the
sampler's events to the store outside the lock that guarded the sampler let two threads interleave: a stale
event's summary list could overwrite a newer one, leaving "ghost" frames on disk that the sampler no longer held,
or missing ones it did. The keeper owns the pipeline's summary and the store together: a caller hands it a
change (a function that touches the pipeline and returns the summary events it caused) and waits; the keeper
runs it and applies its events to the store, then to the surface, before the next change may start. So after
every change the store on disk equals the sampler's summary.

The data path (the inference loop, which makes most changes, and the enhancer worker) runs its change on its own
thread under the keeper's lock: the ordering is the same, and a batch pays no hand-over. What the surface asks
for (a MERL_* parameter, a queries or marks upload, the marks cleared with a topic switch) goes through
``submit`` instead: the change waits in a queue and the keeper's own thread applies it, between two batches,
while the handler that asked waits for the result (with a timeout) and then answers. So a handler never runs a
change on a thread that holds another resource's lock (the parameter server's, the FTP server's), and the
changes from the surface apply one at a time, in the order they came.
"""

from __future__ import annotations

import logging
import queue
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
SUBMIT_TIMEOUT_S = 30.0
"""How long a surface request may wait in the queue for its turn (a CLIP batch on a small board takes seconds;
a ground station re-sends a PARAM_SET it got no answer to long before this)."""


class ChangeTimeout(ValueError):
    """A submitted change did not start within its timeout; it never will (it was withdrawn)."""


class _Pending:
    """One submitted change and, once it ran, its result or error."""

    def __init__(self, fn: Callable[[], Any], events_of: Callable[[Any], list[SummaryEvent]] | None) -> None:
        self.fn = fn
        self.events_of = events_of
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None
        self._state_lock = threading.Lock()
        self.state = "waiting"
        """waiting -> running -> done, or waiting -> withdrawn (its submitter stopped waiting)."""

    def take(self) -> bool:
        """The keeper's thread claims it; False when its submitter already withdrew it."""
        with self._state_lock:
            if self.state != "waiting":
                return False
            self.state = "running"
            return True

    def withdraw(self) -> bool:
        """The submitter gives up; False when the change already started (then it must be waited for)."""
        with self._state_lock:
            if self.state != "waiting":
                return False
            self.state = "withdrawn"
            return True


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
        self._queue: queue.SimpleQueue[_Pending | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None

    # ---- the keeper's own thread: changes the surface asked for ---------------------------------------------
    def start(self) -> None:
        """Start the thread that applies submitted changes (before any handler may submit one)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="summary-keeper", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Finish the change in hand, then end the thread; changes still waiting are refused."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=SUBMIT_TIMEOUT_S)
            self._thread = None

    def submit(self, fn: Callable[[], T], events_of: Callable[[T], list[SummaryEvent]] | None = None, *,
               timeout: float = SUBMIT_TIMEOUT_S) -> T:
        """Have the keeper's thread run ``change(fn, events_of)``; wait for it and return its result (or raise its
        error). ``ChangeTimeout`` when it could not start within ``timeout`` (it is then never applied).

        Called on the keeper's thread itself (a change that submits another) or before ``start``, it runs at once.
        """
        if self._thread is None or threading.current_thread() is self._thread:
            return self.change(fn, events_of)
        pending = _Pending(fn, events_of)
        self._queue.put(pending)
        if not pending.done.wait(timeout) and pending.withdraw():
            raise ChangeTimeout(f"the summary keeper was busy for over {timeout:g} s")
        pending.done.wait()  # it started in time: its outcome is what the surface must hear
        if pending.error is not None:
            raise pending.error
        return pending.result

    def _run(self) -> None:
        while True:
            pending = self._queue.get()
            if pending is None:
                break
            with self.lock:  # the batch in hand ends first; until then its submitter may still withdraw it
                if not pending.take():
                    continue
                try:
                    pending.result = self.change(pending.fn, pending.events_of)
                except BaseException as err:  # noqa: BLE001 - handed to the submitter, which answers the surface
                    pending.error = err
            pending.done.set()
        while True:  # stopping: nothing waiting is applied any more
            try:
                left = self._queue.get_nowait()
            except queue.Empty:
                return
            if left is not None and left.withdraw():
                left.error = ChangeTimeout("the companion is stopping")
                left.done.set()

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
