"""The gallery's earlier dives: their captures (``archived`` in gallery.json, thumbnails under ``dives/<dive>/``) and
the dive ids seen, both bounded whoever sends.

A capture or an index naming a dive never seen before files the current dive here; a late message of a dive
remembered here is ignored. Past ``MAX_ARCHIVED`` captures the first archived is forgotten and its thumbnail deleted
(a dive folder left empty goes too), counted in ``dropped``, and so is its full frame; once a dive's last archived
capture goes, its folder of full frames (``full/<dive>/``) goes too; past ``MAX_DIVES`` ids the oldest is forgotten. A sender
without the key that names a new dive in every capture grew both for good. The ``Gallery`` owns the archive and
calls it under its own lock.
"""

from __future__ import annotations

import logging
import shutil
from collections import Counter, deque
from pathlib import Path

from companion.topside.capture import Capture, safe_dive
from companion.topside.gallery_json import capture_text, list_text
from companion.topside.thumbnail_files import forget_thumbnail, move_thumbnail

log = logging.getLogger("merlion.surface")

MAX_ARCHIVED = 4096
"""Captures of earlier dives kept (with their thumbnails under ``dives/``); the first archived go first. A real dive
leaves its summary and its trimmed frames (1,440 in four hours): a day of dives fits (a folder a day), while a
sender naming a new dive in each capture no longer grows gallery.json (4,096 archived add 2.2 MB, 0.06 s a write)."""
MAX_DIVES = 256
"""Dive ids remembered (a late message of one of them is ignored); the oldest are forgotten first."""


class DiveArchive:
    """Captures of earlier dives, in the order they were filed away, and the dive ids seen, oldest first."""

    def __init__(self, root: Path, *, max_archived: int = MAX_ARCHIVED, max_dives: int = MAX_DIVES) -> None:
        self.root = root
        self.max_archived, self.max_dives = max_archived, max_dives
        self.captures: deque[Capture] = deque()
        """At most ``max_archived`` once ``bound`` ran."""
        self.dives: list[str] = []
        self.dropped = 0
        """Captures of earlier dives forgotten beyond ``max_archived`` (their thumbnails deleted)."""
        self._texts: deque[str] = deque()
        """Each archived capture's gallery.json text (an archived capture never changes), beside ``captures``."""
        self._text: str | None = None
        """The whole ``archived`` list's text, until the archive changes."""
        self._per_dive: Counter[str] = Counter()
        """Archived captures by dive folder name (``unknown`` for none)."""

    def load(self, data: dict) -> None:
        """What gallery.json kept (``archived``, ``dives``, ``archived_dropped``); a bad value raises for the
        gallery to report."""
        self.captures = deque(Capture.from_dict(item) for item in data.get("archived", []))
        self.dives = [str(d) for d in data.get("dives", [])]
        self.dropped = int(data.get("archived_dropped") or 0)
        self._texts = deque(capture_text(c) for c in self.captures)
        self._per_dive = Counter(c.dive or "unknown" for c in self.captures)
        self._text = None

    def knows(self, dive: str) -> bool:
        return dive in self.dives

    def file_away(self, captures, dive: str | None) -> None:
        """File the current dive's ``captures`` (of ``dive``, None from a companion that named none) under
        ``dives/<dive>/``: thumbnails moved, none of them in a summary any more."""
        folder = f"dives/{dive or 'unknown'}"
        for cap in captures:
            cap.dive = cap.dive or dive
            move_thumbnail(self.root, cap, f"{folder}/{'summary' if cap.in_summary else 'removed'}")
            cap.in_summary = False
            self.captures.append(cap)
            self._texts.append(capture_text(cap))
            self._per_dive[cap.dive or "unknown"] += 1
        self._text = None

    def start_dive(self, previous: str | None, dive: str) -> None:
        """``dive`` is now shown, ``previous`` (if any) filed: both are remembered."""
        if previous and previous not in self.dives:
            self.dives.append(previous)
        self.dives.append(dive)

    def bound(self, current: str | None) -> bool:
        """Past ``max_archived`` captures the first archived is forgotten and its thumbnail deleted; past
        ``max_dives`` ids the oldest other than ``current`` is forgotten. True if anything was."""
        dropped = 0
        while len(self.captures) > self.max_archived:
            cap = self.captures.popleft()
            self._texts.popleft()
            forget_thumbnail(self.root, cap)
            self._forget_full_frames(cap, current)
            dropped += 1
        changed = bool(dropped)
        if dropped:
            if not self.dropped:
                log.warning("more than %d captures of earlier dives: the first archived are forgotten, thumbnails "
                            "and all (archived_dropped)", self.max_archived)
            self.dropped += dropped
            self._text = None
        if len(self.dives) > self.max_dives:
            gone = set([d for d in self.dives if d != current][: len(self.dives) - self.max_dives])
            self.dives = [d for d in self.dives if d not in gone]
            changed = True
        return changed

    def text(self) -> str:
        """The ``archived`` list as gallery.json holds it (joined again only after the archive changed)."""
        if self._text is None:
            self._text = list_text(list(self._texts))
        return self._text

    def _forget_full_frames(self, cap: Capture, current: str | None) -> None:
        """The full frame fetched of a forgotten capture, and ``full/<dive>/`` once none of its dive is archived.
        Never the current dive's (a dive id forgotten and named again is current while its old captures wait
        here); a dive id that is no safe name (a hand-edited gallery.json) names no folder."""
        dive = cap.dive or "unknown"
        self._per_dive[dive] -= 1
        last = self._per_dive[dive] <= 0
        if last:
            del self._per_dive[dive]
        if dive == (current or "unknown"):
            return
        try:
            folder = self.root / "full" / safe_dive(dive)
        except ValueError:
            return
        if last:
            shutil.rmtree(folder, ignore_errors=True)
        else:
            (folder / f"{int(cap.image_index)}.jpg").unlink(missing_ok=True)
