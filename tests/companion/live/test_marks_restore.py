"""Saved marks at start (in-process, no vehicle link): re-applied under the same query, ignored under another."""

from __future__ import annotations

import logging
from pathlib import Path

from companion.config import build_config
from companion.live.companion import LiveCompanion
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.vision.feedback import MarkedPreSampler
from tests.waiting import wait_until

QUERY = "underwater image with fish"


def _config(store: Path):
    return build_config({
        "source": {"uri": "synthetic://dive?seconds=2&width=160&height=96", "fps": 10, "realtime": False},
        "encoder": {"name": "visual"}, "queries": {"positive": QUERY, "tau_ss": 0.5},
        "mavlink": {"connection": None}, "store": {"dir": str(store)},
    })


def _run(store: Path, until=None) -> LiveCompanion:
    app = LiveCompanion(_config(store))
    app.start()
    try:
        if until is not None:
            assert wait_until(lambda: until(app), 30), "frames stored"
    finally:
        app.stop()
    return app


def test_saved_marks_come_back_only_under_their_query(tmp_path: Path, caplog) -> None:
    store = tmp_path / "store"
    first = _run(store, until=lambda a: len(a.store.summary) >= 2)
    held = first.store.summary
    marks = MarksFile(store / "marks.json")

    marks.save(SavedMarks([held[0]], [held[1]], QUERY))
    again = _run(store)
    assert again.marks == SavedMarks([held[0]], [held[1]], QUERY)
    assert isinstance(again.pipeline.presampler, MarkedPreSampler)
    assert again.pipeline.presampler.weight == 0.5  # one mark of each kind: as much as the query

    marks.save(SavedMarks([held[0]], [], "underwater image of a wreck"))
    with caplog.at_level(logging.INFO, logger="companion.live"):
        other = _run(store)
    assert not other.marks
    assert not isinstance(other.pipeline.presampler, MarkedPreSampler)
    assert "saved marks were given for 'underwater image of a wreck'" in caplog.text

    marks.save(SavedMarks([10_000], [], QUERY))  # a frame the store never had: the start goes on unmarked
    with caplog.at_level(logging.WARNING, logger="companion.live"):
        missing = _run(store)
    assert not missing.marks
    assert "image 10000 is not in the store" in caplog.text
