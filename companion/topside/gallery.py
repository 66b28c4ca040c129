"""The surface gallery on disk: thumbnails plus a JSON and a CSV log of their tags, mirroring the summary.

Layout of DIR:
- ``summary/<n>.<ext>``: the thumbnails of the frames now in the companion's summary (exactly those);
- ``removed/<n>.<ext>``: thumbnails of frames trimmed out since (kept: nothing received is thrown away);
- ``gallery.json``: every capture ever seen with its tags (its topic among them) and whether it is in the summary,
  and the topics the companion follows (rewritten atomically);
- ``log.csv``: one appended row per event (added, thumbnail, tags, removed, dive), for spreadsheets and audits;
- ``dives/<dive>/summary|removed/<n>.<ext>``: the thumbnails of earlier dives.

Image indices restart when the vehicle's store is reset (a new dive), so a capture is known by its dive id (from
its ``file_url``, ``mftp://summary/<dive>/<n>.jpg``, or index.json) plus its index. The gallery holds one
current dive; a capture of a dive never seen before files the current one away under ``dives/`` first, and a
late message of an earlier dive is ignored, so old thumbnails never show under new captures.

What is kept is bounded, whoever sends (without a signing key anyone on the tether can speak as the companion):
the frames in the current summary always (up to ``MAX_SUMMARY``, more than a companion can hold; past it the frame
that entered first leaves the summary as if trimmed); of the frames trimmed out, the newest ``MAX_HISTORY`` of the
dive, the first trimmed being dropped first (its thumbnail deleted), counted in ``history_dropped``; of earlier
dives, the newest ``MAX_ARCHIVED`` captures (the first archived dropped first, thumbnails and all, counted in
``archived_dropped``) and the newest ``MAX_DIVES`` dive ids; and ``MAX_LOG_ROWS`` rows of log.csv per run (then
one ``log_full`` row; the rest counted in ``log_rows_dropped``).

A gallery reopened on the same DIR continues where it stopped, so restarting the tool mid-dive loses nothing; a
folder written before topics existed opens too (its captures' topic is unknown, and its log.csv keeps its columns).

The gallery owns its parts and calls them under its lock: ``dive_archive.DiveArchive`` (the earlier dives),
``gallery_log.GalleryLog`` (log.csv); ``capture`` holds the records, ``thumbnail_files`` moves and deletes
thumbnails.
"""

from __future__ import annotations

import json
import logging
import math
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.errors import MerlionError
from companion.topside.capture import Capture, Topic, safe_dive
from companion.topside.dive_archive import MAX_ARCHIVED, MAX_DIVES, DiveArchive
from companion.topside.gallery_json import GalleryText, capture_text
from companion.topside.gallery_log import LOG_COLUMNS, MAX_LOG_ROWS, GalleryLog
from companion.topside.gallery_writer import GalleryWriter
from companion.topside.thumbnail_files import move_thumbnail

__all__ = ["LOG_COLUMNS", "MAX_ARCHIVED", "MAX_DIVES", "MAX_HISTORY", "MAX_LOG_ROWS", "MAX_SUMMARY", "Capture",
           "Gallery", "Topic", "safe_dive"]

log = logging.getLogger("merlion.surface")

MAX_SUMMARY = 8192
"""Frames of the current summary kept: a companion holds at most 8 topics of k <= 1,000 frames."""
MAX_HISTORY = 4096
"""Frames of the current dive trimmed out of its summary that are kept (with their thumbnails); the first trimmed
goes first. A summary of 6 that takes a new frame every 10 s trims 1,440 in four hours."""


class Gallery:
    """Thread-safe: the receive loop writes, the web server reads snapshots."""

    def __init__(self, root: str | os.PathLike[str], *, clock: Callable[[], float] = time.monotonic,
                 max_summary: int = MAX_SUMMARY, max_history: int = MAX_HISTORY,
                 max_log_rows: int = MAX_LOG_ROWS, max_archived: int = MAX_ARCHIVED,
                 max_dives: int = MAX_DIVES) -> None:
        self.root = Path(root)
        self.max_summary, self.max_history = max_summary, max_history
        self._clock = clock
        self.write_every_s = 0.0
        """gallery.json is rewritten at most this often (0: on every change); see ``defer_writes``."""
        self._json_due = False
        self._json_at = -math.inf
        self.json_writes = 0
        try:
            (self.root / "summary").mkdir(parents=True, exist_ok=True)
            (self.root / "removed").mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise MerlionError(f"{self.root}: cannot create the gallery folder ({err.strerror})") from None
        self._lock = threading.Lock()
        self._captures: dict[int, Capture] = {}
        self._in_summary: OrderedDict[int, None] = OrderedDict()
        """Image indices in the summary, in the order they entered it."""
        self._history: OrderedDict[int, None] = OrderedDict()
        """Image indices of the current dive out of the summary, in the order they left it."""
        self.history_dropped = 0
        """Trimmed frames forgotten beyond ``max_history`` (all dives of this folder)."""
        self.archive = DiveArchive(self.root, max_archived=max_archived, max_dives=max_dives)
        """The earlier dives: their captures and the dive ids seen."""
        self.dive: str | None = None
        """The dive now shown (None until a companion names one)."""
        self._topics: list[Topic] = []
        self._json = self.root / "gallery.json"
        self._texts: dict[int, str] = {}
        """Each current capture's gallery.json text, until it changes (``_persist`` forgets it)."""
        self._writer = GalleryWriter(self._json)
        self._load()
        self.log = GalleryLog(self.root / "log.csv", max_log_rows)

    archived_dropped = property(lambda self: self.archive.dropped)
    """Captures of earlier dives forgotten beyond ``max_archived`` (their thumbnails deleted)."""
    log_rows = property(lambda self: self.log.rows)
    """Rows appended to log.csv by this run."""
    log_rows_dropped = property(lambda self: self.log.rows_dropped)
    """Events of this run past ``max_log_rows``: not in log.csv (gallery.json still has the state)."""

    def _load(self) -> None:
        if not self._json.exists():
            return
        try:
            data = json.loads(self._json.read_text(encoding="utf-8"))
            for item in data.get("captures", []):
                cap = Capture.from_dict(item)
                self._captures[cap.image_index] = cap
            self.archive.load(data)
            self.dive = safe_dive(data["dive"]) if data.get("dive") else None  # a folder name, see safe_dive
            self._topics = [Topic.from_dict(t) for t in data.get("topics", [])]
            self.history_dropped = int(data.get("history_dropped") or 0)
        except (OSError, ValueError, TypeError, AttributeError, KeyError) as err:
            raise MerlionError(f"{self._json}: not a gallery file this tool can read ({err})") from None
        for cap in sorted(self._captures.values(), key=lambda c: (c.removed_at or c.announced_at or 0.0,
                                                                   c.image_index)):
            self._track(cap)
        self._bound_archive()  # a folder from a tool without the bound, or one run with a larger one

    # --- reading -------------------------------------------------------------------------------------------

    def get(self, image_index: int) -> Capture | None:
        with self._lock:
            cap = self._captures.get(image_index)
            return None if cap is None else cap.copy()

    def captures(self) -> list[Capture]:
        """Every capture ever seen, newest (highest image index) first."""
        with self._lock:
            return [c.copy() for _, c in sorted(self._captures.items(), reverse=True)]

    def summary(self) -> list[Capture]:
        """The frames now in the companion's summary, newest first."""
        return [c for c in self.captures() if c.in_summary]

    def archived(self) -> list[Capture]:
        """Captures of earlier dives, oldest dive first."""
        with self._lock:
            return [c.copy() for c in self.archive.captures]

    def dives(self) -> list[str]:
        with self._lock:
            return list(self.archive.dives)

    def topics(self) -> list[Topic]:
        """The topics the companion follows, in its order (empty until an index.json listed them)."""
        with self._lock:
            return list(self._topics)

    def missing_thumbnails(self) -> list[int]:
        with self._lock:
            return sorted(i for i, c in self._captures.items() if c.in_summary and c.thumbnail is None)

    def full_path(self, image_index: int, dive: str | None) -> Path:
        """Where a full-resolution frame fetched on demand is kept: ``full/<dive>/<n>.jpg``."""
        return self.root / "full" / (safe_dive(dive) if dive else "unknown") / f"{int(image_index)}.jpg"

    # --- writing -------------------------------------------------------------------------------------------

    def defer_writes(self, every_s: float) -> None:
        """Rewrite gallery.json at most every ``every_s`` seconds, on the writer thread (log.csv still gets its row
        at once, here). Each rewrite is the whole file, fsynced twice: a companion announcing captures as fast as it
        can had the tool write it once per message, the work growing with every capture. Whoever sets this calls
        ``flush_due`` often and ``flush`` at the end, so the last state is always written."""
        self.write_every_s = every_s

    def flush_due(self) -> None:
        """Hand gallery.json's state to the writer if a change waits and the interval has passed."""
        with self._lock:
            if self._json_due and self._clock() - self._json_at >= self.write_every_s:
                self._write_json()

    def flush(self) -> None:
        """Write gallery.json now if a change waits, and return once the latest state is on disk."""
        with self._lock:
            if self._json_due:
                self._write_json()
        self._writer.wait()

    def wait_written(self, timeout: float | None = None) -> None:
        """Return once every state handed to the writer thread is on disk (TimeoutError after ``timeout``)."""
        self._writer.wait(timeout)

    def add_full(self, image_index: int, data: bytes, dive: str | None) -> Path:
        path = self.full_path(image_index, dive)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, data)
        return path

    def use_dive(self, dive: str | None) -> str:
        """What a message of ``dive`` means here: ``"current"`` (file it), ``"new"`` (the vehicle's store was reset:
        the gallery now shows that dive, the old one is filed under ``dives/``) or ``"old"`` (a late message of an
        earlier dive: ignore it). A companion that names no dive is always current; a dive id that is not a safe
        name (``safe_dive``) is a ValueError."""
        if not dive:
            return "current"
        safe_dive(dive)
        with self._lock:
            if dive == self.dive:
                return "current"
            if self.archive.knows(dive):
                return "old"
            if self._captures:
                self.archive.file_away(self._captures.values(), self.dive)
                self._captures = {}
                self._texts.clear()
                self._in_summary.clear()
                self._history.clear()
            self.archive.start_dive(self.dive, dive)
            self.dive = dive
            self._bound_archive()
            self._persist("dive", Capture(image_index=-1, dive=dive))
            return "new"

    def set_topics(self, topics: list[Topic]) -> bool:
        """The topics index.json lists now; True if they changed (then gallery.json says so at once)."""
        with self._lock:
            if topics == self._topics:
                return False
            self._topics = list(topics)
            self._persist("topics", Capture(image_index=-1, dive=self.dive))
            return True

    def announce(self, cap: Capture) -> bool:
        """A capture was announced (or re-announced); True if it is new to us. Known tags are kept."""
        with self._lock:
            old = self._captures.get(cap.image_index)
            cap.dive = cap.dive or self.dive
            if old is None:
                cap.announced_at = cap.announced_at or time.time()
                self._captures[cap.image_index] = cap
                self._track(cap)
                self._persist("added", cap)
                self._bound()
                return True
            changed = False
            for f in fields(Capture):
                if f.name in ("thumbnail", "thumbnail_via", "thumbnail_bytes", "in_summary", "announced_at",
                              "removed_at"):
                    continue
                value = getattr(cap, f.name)
                if value is not None and getattr(old, f.name) != value:
                    setattr(old, f.name, value)
                    changed = True
            if changed:
                self._persist("tags", old)
            return False

    def update_tags(self, image_index: int, **tags) -> bool:
        """Fill in tags learnt later (score and heading from index.json); True if anything changed."""
        with self._lock:
            cap = self._captures.get(image_index)
            if cap is None:
                return False
            changed = False
            for key, value in tags.items():
                if value is not None and getattr(cap, key) != value:
                    setattr(cap, key, value)
                    changed = True
            if changed:
                self._persist("tags", cap)
            return changed

    def add_thumbnail(self, image_index: int, data: bytes, *, ext: str = "jpg", via: str = "push") -> Path:
        """Store a thumbnail for a known capture (in summary/ or removed/, wherever the frame now is)."""
        with self._lock:
            cap = self._captures.get(image_index)
            if cap is None:
                cap = Capture(image_index=image_index, dive=self.dive, announced_at=time.time())
                self._captures[image_index] = cap
                self._track(cap)
            folder = "summary" if cap.in_summary else "removed"
            rel = f"{folder}/{image_index}.{ext}"
            path = self.root / rel
            atomic_write(path, data)
            if cap.thumbnail and cap.thumbnail != rel:
                (self.root / cap.thumbnail).unlink(missing_ok=True)
            cap.thumbnail, cap.thumbnail_via, cap.thumbnail_bytes = rel, via, len(data)
            self._persist("thumbnail", cap)
            self._bound()
            return path

    def remove(self, image_index: int) -> bool:
        """The frame was trimmed out of the summary: move its thumbnail aside; True if it was in the summary.

        A trim of a frame not heard of yet (its capture lost or still on the way) is remembered, so that a late
        capture or push for it lands in removed/ and never puts it back into the summary.
        """
        with self._lock:
            cap = self._captures.get(image_index)
            if cap is None:
                now = time.time()
                cap = Capture(image_index=image_index, dive=self.dive, in_summary=False, announced_at=now,
                              removed_at=now)
                self._captures[image_index] = cap
                self._track(cap)
                self._persist("removed", cap)
                self._bound()
                return False
            if not cap.in_summary:
                return False
            self._trim(cap)
            self._bound()
            return True

    def _trim(self, cap: Capture) -> None:
        """Caller holds the lock."""
        cap.in_summary = False
        cap.removed_at = time.time()
        move_thumbnail(self.root, cap, "removed")
        self._track(cap)
        self._persist("removed", cap)

    def _track(self, cap: Capture) -> None:
        """Keep ``cap`` in the order of the part it now belongs to (caller holds the lock)."""
        i = cap.image_index
        if cap.in_summary:
            self._history.pop(i, None)
            self._in_summary[i] = None
        else:
            self._in_summary.pop(i, None)
            self._history[i] = None

    def _bound(self) -> None:
        """Caller holds the lock. The summary past ``max_summary``: the frame that entered first leaves it; the
        history past ``max_history``: the frame that left first is forgotten, and its thumbnail deleted."""
        while len(self._in_summary) > self.max_summary:
            self._trim(self._captures[next(iter(self._in_summary))])
        dropped = 0
        while len(self._history) > self.max_history:
            index, _ = self._history.popitem(last=False)
            cap = self._captures.pop(index)
            self._texts.pop(index, None)
            if cap.thumbnail:
                (self.root / cap.thumbnail).unlink(missing_ok=True)
            dropped += 1
        if dropped:
            if not self.history_dropped:
                log.warning("more than %d frames trimmed out of this dive's summary: the first trimmed are "
                            "forgotten, thumbnails and all (history_dropped)", self.max_history)
            self.history_dropped += dropped
            self._json_due = True

    def _bound_archive(self) -> None:
        """Caller holds the lock (or is ``_load``): the archive within its bounds (``DiveArchive.bound``)."""
        if self.archive.bound(self.dive):
            self._json_due = True

    def mirror(self, summary: list[int], announced_before: float | None = None) -> list[int]:
        """Make the gallery's current summary ``summary`` (from index.json); return indices removed.

        Frames announced after ``announced_before`` (when the index was asked for) are kept: the index was
        built before they existed. Likewise frames whose trim arrived after that moment stay out: the index was
        built before the trim, and a trimmed frame never comes back (a frame re-entering gets a new index).
        """
        wanted = set(summary)
        with self._lock:
            gone = [i for i, c in self._captures.items() if c.in_summary and i not in wanted
                    and (announced_before is None or (c.announced_at or 0.0) < announced_before)]
            back = [i for i, c in self._captures.items() if not c.in_summary and i in wanted
                    and (announced_before is None or (c.removed_at or 0.0) < announced_before)]
        for i in gone:
            self.remove(i)
        for i in back:
            self._restore(i)
        for i in wanted:
            if self.get(i) is None:
                self.announce(Capture(image_index=i))
        return sorted(gone)

    def _restore(self, image_index: int) -> None:
        with self._lock:
            cap = self._captures.get(image_index)
            if cap is None:
                return  # forgotten meanwhile (beyond max_history)
            cap.in_summary, cap.removed_at = True, None
            move_thumbnail(self.root, cap, "summary")
            self._track(cap)
            self._persist("added", cap)
            self._bound()

    def _persist(self, event: str, cap: Capture) -> None:
        """Caller holds the lock. JSON first (the state, unless written less than ``write_every_s`` ago: then it
        waits for ``flush_due``), then the CSV row (the history)."""
        self._texts.pop(cap.image_index, None)
        self._json_due = True
        if self._clock() - self._json_at >= self.write_every_s:
            self._write_json()
        self.log.append(event, cap, self.dive)

    def _write_json(self) -> None:
        """Caller holds the lock. The state as text (each capture's kept until it changes): written here when the
        gallery writes through, else handed to the writer thread, which owns the file."""
        texts, captures = self._texts, self._captures
        state = GalleryText(
            updated=time.time(),
            dive=self.dive,
            dives=tuple(self.archive.dives),
            summary=tuple(sorted(i for i, c in captures.items() if c.in_summary)),
            captures=tuple(texts.get(i) or texts.setdefault(i, capture_text(captures[i])) for i in sorted(captures)),
            archived=self.archive.text(),
            topics=tuple(t.to_dict() for t in self._topics),
            history_dropped=self.history_dropped,
            archived_dropped=self.archive.dropped,
        )
        if self.write_every_s > 0:
            self._writer.hand_over(state)
        else:
            self._writer.write_now(state)
        self._json_due, self._json_at = False, self._clock()
        self.json_writes += 1
