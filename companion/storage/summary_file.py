"""The store's ``summary.json`` read back field by field, so a damaged field costs that field and no other.

Read whole, one bad value (a next image index of "abc", say) made the store throw the file away: the summary was
rebuilt from the change log and the dive id was lost, so the surface filed the same dive under a new one. Here
the summary list, the next image index and the dive id are each taken or dropped on their own, with one warning
line each. A next index past ``index_reservation.USED_UP`` (every index MAVLink carries handed out) was never
handed out and is dropped; the frames on disk and ``next_index`` still give the floor.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

from companion.storage.index_reservation import MAX_INDEX, USED_UP, valid_index, valid_next

log = logging.getLogger("companion.storage.store")


@dataclass
class SavedSummary:
    summary: list[int] | None = None
    """The image indices held; None when unreadable (the store rebuilds it from the change log)."""
    next_index: int = 0
    dive: str = ""
    dropped: bool = False
    """A field was dropped: the store writes the file again, so the warning is not repeated at every start."""


def read_summary_file(path: Path) -> SavedSummary:
    """What ``path`` holds ([] summary when it does not exist)."""
    if not path.exists():
        return SavedSummary(summary=[])
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as err:
        log.warning("%s: unreadable (%s); rebuilding the summary from the change log", path, err)
        return SavedSummary(dropped=True)
    saved = SavedSummary(dive=data["dive"] if isinstance(data.get("dive"), str) else "")
    summary = data.get("summary", [])
    if isinstance(summary, list) and all(valid_index(i) for i in summary):
        saved.summary = list(summary)
    else:
        log.warning("%s: summary %.80r is not a list of image indices; rebuilding it from the change log", path,
                    summary)
        saved.dropped = True
    claim = data.get("next_image_index", 0)
    if valid_next(claim):
        saved.next_index = claim
    else:
        log.warning("%s: next_image_index %.40r is not one MAVLink can announce (0-%d, or %d once all are used); "
                    "ignored, the frames on disk give the next one", path, claim, MAX_INDEX, USED_UP)
        saved.dropped = True
    return saved
