"""The operator's marks on disk (``marks.json`` in the store), so a restart keeps what the operator taught.

Marks name summary frames by image index ("more like this" / "not this"); the store keeps those frames' images,
so the app re-derives the example features from them after a restart. Marks belong to the queries they were
given under (clearing them is part of a query change), so the file records the positive query too and the app
re-applies them only while that query is still the one in force. With several topics (``queries.topics``) a
mark teaches the topic of the frame it names, so the file records each topic's positive query (``topics``,
name -> query) and a mark is re-applied only while its own topic's query is unchanged; ``query`` (the first
topic's) stays for files written before topics, which an older merlion still reads.

Written with ``atomic_write`` and versioned like ``params.json`` (``companion.storage.versioned``): a damaged file
is logged and ignored (no marks), a file from a newer merlion stops the start and is left untouched.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.storage.versioned import upgrade

log = logging.getLogger(__name__)

FILE_VERSION = 1


@dataclass
class SavedMarks:
    """Image indices marked "like" and "unlike", and the positive query in force when they were given."""

    like: list[int] = field(default_factory=list)
    unlike: list[int] = field(default_factory=list)
    query: str = ""
    topics: dict[str, str] = field(default_factory=dict)
    """Each topic's positive query when the marks were given (empty in a file written before topics)."""

    def __bool__(self) -> bool:
        return bool(self.like or self.unlike)

    def query_of(self, topic: str) -> str:
        """The positive query ``topic`` had when the marks were given (a file from before topics: ``query``)."""
        return self.topics.get(topic, "") if self.topics else self.query


def _indices(value: object, key: str) -> list[int]:
    if not isinstance(value, list) or not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0
                                              for i in value):
        raise TypeError(f"{key} is not a list of image indices")
    return list(value)


class MarksFile:
    """``load()`` the saved marks; ``save(marks)`` replaces them; ``clear()`` removes them."""

    def __init__(self, path: str | os.PathLike[str], *, version: str = "",
                 guard: Callable[[], None] | None = None) -> None:
        self.path = Path(path)
        self.version = version
        self.guard = guard or (lambda: None)
        """Asked before a write (``StoreLock.check``): OSError when the store folder is no longer this run's."""

    def load(self) -> SavedMarks:
        """The saved marks (none when absent or damaged); raises NewerFileError for a newer version's file."""
        if not self.path.exists():
            return SavedMarks()
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            log.warning("%s: ignoring saved marks (%s)", self.path, err)
            return SavedMarks()
        try:
            data = upgrade(self.path, data, current=FILE_VERSION, migrations={}, app_version=self.version)
            query = data.get("query", "")
            if not isinstance(query, str):
                raise TypeError("query is not text")
            topics = data.get("topics", {})
            if not isinstance(topics, dict) or not all(isinstance(k, str) and isinstance(v, str)
                                                       for k, v in topics.items()):
                raise TypeError("topics is not a map of topic names to queries")
            return SavedMarks(_indices(data.get("like", []), "like"), _indices(data.get("unlike", []), "unlike"),
                              query, dict(topics))
        except (ValueError, TypeError) as err:
            log.warning("%s: ignoring saved marks (%s)", self.path, err)
            return SavedMarks()

    def save(self, marks: SavedMarks) -> None:
        self.guard()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = {"version": FILE_VERSION, "written_by": self.version or "unknown", "query": marks.query,
                "topics": marks.topics, "like": marks.like, "unlike": marks.unlike}
        atomic_write(self.path, json.dumps(body, indent=1) + "\n")

    def clear(self) -> None:
        self.guard()
        self.path.unlink(missing_ok=True)
