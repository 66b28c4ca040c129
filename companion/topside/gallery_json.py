"""gallery.json's text, put together from pieces serialised once.

At every cap the file holds 16,384 captures (10.8 MB with every tag) and a rewrite was ``json.dumps(doc, indent=1)``
of all of them (``indent`` takes the pure-Python encoder): 0.34 s on the receive loop, up to 4 times a second. A
capture changes a few fields at a time and an archived one never, so each capture's text is kept (``capture_text``)
and the document is joined from them (``GalleryText.render``): the same bytes as ``json.dumps(doc, indent=1)``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from companion.topside.capture import Capture


def capture_text(cap: Capture) -> str:
    """``cap`` as it stands in a list under the document's top level (items at indent 2, their fields at 3)."""
    return json.dumps(cap.to_dict(), indent=1).replace("\n", "\n  ")


def list_text(items: list[str]) -> str:
    """A top-level value that is a list of already serialised items."""
    return "[\n  " + ",\n  ".join(items) + "\n ]" if items else "[]"


def value_text(value: object) -> str:
    """A small top-level value, serialised now."""
    return json.dumps(value, indent=1).replace("\n", "\n ")


@dataclass(frozen=True)
class GalleryText:
    """One state of the gallery, every piece already immutable text (or plain values copied for it), so another
    thread may render it while the gallery changes on."""

    updated: float
    dive: str | None
    dives: tuple[str, ...]
    summary: tuple[int, ...]
    captures: tuple[str, ...]
    archived: str
    """The whole ``archived`` list, as ``list_text`` made it."""
    topics: tuple[dict, ...]
    history_dropped: int
    archived_dropped: int

    def render(self) -> str:
        parts = [
            ("updated", value_text(self.updated)),
            ("dive", value_text(self.dive)),
            ("dives", value_text(list(self.dives))),
            ("summary", list_text([str(i) for i in self.summary])),
            ("captures", list_text(list(self.captures))),
            ("archived", self.archived),
            ("topics", value_text(list(self.topics))),
            ("history_dropped", value_text(self.history_dropped)),
            ("archived_dropped", value_text(self.archived_dropped)),
        ]
        return "{\n" + ",\n".join(f" {json.dumps(key)}: {text}" for key, text in parts) + "\n}"
