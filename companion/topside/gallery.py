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
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import re
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.errors import MerlionError

log = logging.getLogger("merlion.surface")

MAX_SUMMARY = 8192
"""Frames of the current summary kept: a companion holds at most 8 topics of k <= 1,000 frames."""
MAX_HISTORY = 4096
"""Frames of the current dive trimmed out of its summary that are kept (with their thumbnails); the first trimmed
goes first. A summary of 6 that takes a new frame every 10 s trims 1,440 in four hours."""

MAX_ARCHIVED = 4096
"""Captures of earlier dives kept (with their thumbnails under ``dives/``); the first archived go first. A real dive
leaves its summary and its trimmed frames (1,440 in four hours): a day of dives fits (a folder a day), while a
sender naming a new dive in each capture no longer grows gallery.json (4,096 archived add 2.2 MB, 0.06 s a write)."""
MAX_DIVES = 256
"""Dive ids remembered (a late message of one of them is ignored); the oldest are forgotten first."""

MAX_LOG_ROWS = 100_000
"""Rows appended to log.csv per run (about 100 bytes each): a day's diving writes a few thousand."""

_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")


def safe_dive(dive: str) -> str:
    """``dive`` when it may name a folder in DIR, else ValueError. A dive id comes from the wire (a capture's
    ``file_url``, index.json) and becomes ``dives/<dive>/`` and ``full/<dive>/``: ``..`` or ``/tmp/x`` there would
    move thumbnails, or write a full frame the page asked for, outside DIR. The companion makes 8 hex digits."""
    if not isinstance(dive, str) or not _SAFE_NAME.fullmatch(dive):
        raise ValueError(f"dive id {str(dive)[:80]!r} is not a safe name (letters, digits, _ and -, at most 64)")
    return dive


LOG_COLUMNS = [
    "event", "wall_time", "dive", "image_index", "in_summary", "time_utc", "depth_m", "heading_deg", "score",
    "lat", "lon", "alt_m", "thumbnail", "thumbnail_via", "file_url", "topic", "raw_score",
]


@dataclass(frozen=True)
class Topic:
    """A topic the companion follows, as its index.json states it: the page heads the topic's frames with it."""

    name: str
    positive: str
    negatives: tuple[str, ...] = ()

    @classmethod
    def from_dict(cls, data: dict) -> Topic:
        return cls(str(data["name"]), str(data.get("positive") or ""), tuple(str(n) for n in data.get("negatives") or ()))

    def to_dict(self) -> dict:
        return {"name": self.name, "positive": self.positive, "negatives": list(self.negatives)}


@dataclass
class Capture:
    """One summary frame as the surface knows it; fields the companion has not told us yet are None."""

    image_index: int
    dive: str | None = None
    """The vehicle store's dive id; None from a companion that sends none."""
    time_utc: float | None = None
    """Seconds since epoch at capture (companion clock)."""
    depth_m: float | None = None
    """Metres below the surface (positive down)."""
    heading_deg: float | None = None
    q: list[float] | None = None
    """Attitude quaternion w-x-y-z."""
    lat: float | None = None
    lon: float | None = None
    alt_m: float | None = None
    score: float | None = None
    raw_score: float | None = None
    """The frame's score as captured when ``score`` is its enhanced copy's (index.json); else None."""
    topic: str | None = None
    """The name of the topic whose summary holds it (index.json, or the STATUSTEXT when several are followed);
    None until the companion said (and in a gallery written before topics)."""
    below_threshold: bool | None = None
    """A stand-in (index.json): nothing passed the threshold for a while, so the best frame seen is shown."""
    file_url: str | None = None
    thumbnail: str | None = None
    """Path of the thumbnail relative to DIR, once we have it."""
    thumbnail_via: str | None = None
    """push | ftp."""
    thumbnail_bytes: int | None = None
    thumbnail_crc32: int | None = None
    """CRC-32 (MAVLink FTP flavour) of the companion's thumbnail file, from index.json."""
    in_summary: bool = True
    announced_at: float | None = None
    """Surface wall clock when we first heard of it."""
    removed_at: float | None = None

    @classmethod
    def from_dict(cls, data: dict) -> Capture:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    def to_dict(self) -> dict:
        """Its fields, shallow (``asdict`` deep-copies: 0.22 s for the 12,288 captures a gallery may hold, on the
        receive loop at each gallery.json rewrite); ``q`` is shared, so only for writing out."""
        return {name: getattr(self, name) for name in _CAPTURE_FIELDS}

    def copy(self) -> Capture:
        """A copy a reader may keep (its own ``q``)."""
        return replace(self, q=None if self.q is None else list(self.q))


_CAPTURE_FIELDS = tuple(f.name for f in fields(Capture))


class Gallery:
    """Thread-safe: the receive loop writes, the web server reads snapshots."""

    def __init__(self, root: str | os.PathLike[str], *, clock: Callable[[], float] = time.monotonic,
                 max_summary: int = MAX_SUMMARY, max_history: int = MAX_HISTORY,
                 max_log_rows: int = MAX_LOG_ROWS, max_archived: int = MAX_ARCHIVED,
                 max_dives: int = MAX_DIVES) -> None:
        self.root = Path(root)
        self.max_summary, self.max_history, self.max_log_rows = max_summary, max_history, max_log_rows
        self.max_archived, self.max_dives = max_archived, max_dives
        self.log_rows = 0
        """Rows appended to log.csv by this run."""
        self.log_rows_dropped = 0
        """Events of this run past ``max_log_rows``: not in log.csv (gallery.json still has the state)."""
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
        self._archived: deque[Capture] = deque()
        """Captures of earlier dives, in the order they were filed away (at most ``max_archived``)."""
        self.archived_dropped = 0
        """Captures of earlier dives forgotten beyond ``max_archived`` (their thumbnails deleted)."""
        self.dive: str | None = None
        """The dive now shown (None until a companion names one)."""
        self._dives: list[str] = []
        self._topics: list[Topic] = []
        self._json = self.root / "gallery.json"
        self._csv = self.root / "log.csv"
        self._load()
        self._columns = self._log_columns()

    def _load(self) -> None:
        if not self._json.exists():
            return
        try:
            data = json.loads(self._json.read_text(encoding="utf-8"))
            for item in data.get("captures", []):
                cap = Capture.from_dict(item)
                self._captures[cap.image_index] = cap
            self._archived = deque(Capture.from_dict(item) for item in data.get("archived", []))
            self.dive = safe_dive(data["dive"]) if data.get("dive") else None  # a folder name, see safe_dive
            self._dives = [str(d) for d in data.get("dives", [])]
            self._topics = [Topic.from_dict(t) for t in data.get("topics", [])]
            self.history_dropped = int(data.get("history_dropped") or 0)
            self.archived_dropped = int(data.get("archived_dropped") or 0)
        except (OSError, ValueError, TypeError, AttributeError, KeyError) as err:
            raise MerlionError(f"{self._json}: not a gallery file this tool can read ({err})") from None
        for cap in sorted(self._captures.values(), key=lambda c: (c.removed_at or c.announced_at or 0.0,
                                                                   c.image_index)):
            self._track(cap)
        self._bound_archive()  # a folder from a tool without the bound, or one run with a larger one

    def _log_columns(self) -> list[str]:
        """The columns log.csv already has (a folder from an older tool keeps its header: rows stay aligned)."""
        try:
            with self._csv.open(newline="", encoding="utf-8") as fh:
                header = next(csv.reader(fh), None)
        except FileNotFoundError:
            return list(LOG_COLUMNS)
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise MerlionError(f"{self._csv}: not a log this tool can append to ({err})") from None
        return header if header and set(header) <= set(LOG_COLUMNS) else list(LOG_COLUMNS)

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
            return [c.copy() for c in self._archived]

    def dives(self) -> list[str]:
        with self._lock:
            return list(self._dives)

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
        """Rewrite gallery.json at most every ``every_s`` seconds (log.csv still gets its row at once). Each rewrite
        is the whole file, fsynced twice: a companion announcing captures as fast as it can had the tool write it
        once per message, the work growing with every capture. Whoever sets this calls ``flush_due`` often and
        ``flush`` at the end, so the last state is always written."""
        self.write_every_s = every_s

    def flush_due(self) -> None:
        """Write gallery.json if a change waits and the interval has passed."""
        with self._lock:
            if self._json_due and self._clock() - self._json_at >= self.write_every_s:
                self._write_json()

    def flush(self) -> None:
        """Write gallery.json now if a change waits."""
        with self._lock:
            if self._json_due:
                self._write_json()

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
            if dive in self._dives:
                return "old"
            if self._captures:
                folder = f"dives/{self.dive or 'unknown'}"
                for cap in self._captures.values():
                    cap.dive = cap.dive or self.dive
                    self._move_thumbnail(cap, f"{folder}/{'summary' if cap.in_summary else 'removed'}")
                    cap.in_summary = False
                    self._archived.append(cap)
                self._captures = {}
                self._in_summary.clear()
                self._history.clear()
            if self.dive and self.dive not in self._dives:
                self._dives.append(self.dive)
            self.dive = dive
            self._dives.append(dive)
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
        self._move_thumbnail(cap, "removed")
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
        """Caller holds the lock (or is ``_load``). Earlier dives past ``max_archived`` captures: the first archived
        is forgotten and its thumbnail deleted (a dive folder left empty goes too); past ``max_dives`` ids the
        oldest is forgotten. A sender without the key that names a new dive in every capture grew both for good."""
        dropped = 0
        while len(self._archived) > self.max_archived:
            self._forget_thumbnail(self._archived.popleft())
            dropped += 1
        if dropped:
            if not self.archived_dropped:
                log.warning("more than %d captures of earlier dives: the first archived are forgotten, thumbnails "
                            "and all (archived_dropped)", self.max_archived)
            self.archived_dropped += dropped
            self._json_due = True
        if len(self._dives) > self.max_dives:
            gone = set([d for d in self._dives if d != self.dive][: len(self._dives) - self.max_dives])
            self._dives = [d for d in self._dives if d not in gone]
            self._json_due = True

    def _forget_thumbnail(self, cap: Capture) -> None:
        """Delete an archived capture's thumbnail, and its dive's folders once empty."""
        if not cap.thumbnail:
            return
        path = self.root / cap.thumbnail
        path.unlink(missing_ok=True)
        dives, folder = self.root / "dives", path.parent
        while dives in folder.parents:
            try:
                folder.rmdir()
            except OSError:
                break  # not empty
            folder = folder.parent

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
            self._move_thumbnail(cap, "summary")
            self._track(cap)
            self._persist("added", cap)
            self._bound()

    def _move_thumbnail(self, cap: Capture, folder: str) -> None:
        """Keep a capture's thumbnail in the folder that matches its state (caller holds the lock)."""
        if cap.thumbnail:
            src = self.root / cap.thumbnail
            rel = f"{folder}/{Path(cap.thumbnail).name}"
            if src.exists():
                (self.root / rel).parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, self.root / rel)
            cap.thumbnail = rel

    def _persist(self, event: str, cap: Capture) -> None:
        """Caller holds the lock. JSON first (the state, unless written less than ``write_every_s`` ago: then it
        waits for ``flush_due``), then the CSV row (the history)."""
        self._json_due = True
        if self._clock() - self._json_at >= self.write_every_s:
            self._write_json()
        self._log_row(event, cap)

    def _write_json(self) -> None:
        """Caller holds the lock."""
        doc = {
            "updated": time.time(),
            "dive": self.dive,
            "dives": self._dives,
            "summary": sorted(i for i, c in self._captures.items() if c.in_summary),
            "captures": [c.to_dict() for _, c in sorted(self._captures.items())],
            "archived": [c.to_dict() for c in self._archived],
            "topics": [t.to_dict() for t in self._topics],
            "history_dropped": self.history_dropped,
            "archived_dropped": self.archived_dropped,
        }
        atomic_write(self._json, json.dumps(doc, indent=1))
        self._json_due, self._json_at = False, self._clock()
        self.json_writes += 1

    def _log_row(self, event: str, cap: Capture) -> None:
        """Caller holds the lock. Past ``max_log_rows`` rows this run, one ``log_full`` row and then none (each
        event of a sender announcing without end was a row, the file growing for the whole run)."""
        if self.log_rows > self.max_log_rows:
            self.log_rows_dropped += 1
            return
        if self.log_rows == self.max_log_rows:
            log.warning("%s: %d rows this run: no more are written (log_rows_dropped; gallery.json keeps the "
                        "state)", self._csv, self.max_log_rows)
            self.log_rows_dropped += 1
            event, cap = "log_full", Capture(image_index=-1, dive=self.dive)
        self.log_rows += 1
        new = not self._csv.exists()
        if new:
            self._columns = list(LOG_COLUMNS)
        with self._csv.open("a", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            if new:
                writer.writerow(self._columns)
            row = cap.to_dict()
            row.update(event=event, wall_time=f"{time.time():.3f}")
            writer.writerow(["" if row.get(k) is None else row.get(k) for k in self._columns])
