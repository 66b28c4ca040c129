"""queries.json: the surface's uploaded topics on disk; damaged files ignored, newer ones refused untouched."""

from __future__ import annotations

import json

import pytest

from companion.storage.queries_file import QueriesFile, SavedQueries
from companion.storage.versioned import NewerFileError

FISH = {"name": "fish", "positive": "underwater image with fish", "negatives": ["underwater image without fish"]}
WRECK = {"name": "wreck", "positive": "underwater image of a wreck", "negatives": []}


def test_round_trip(tmp_path):
    f = QueriesFile(tmp_path / "queries.json", version="9.9")
    assert f.load() is None
    f.save(SavedQueries([FISH, WRECK], [FISH]))
    assert f.load() == SavedQueries([FISH, WRECK], [FISH])
    assert json.loads(f.path.read_text())["written_by"] == "9.9"


@pytest.mark.parametrize("body", ["{not json", '{"version": 1, "topics": [], "configured": []}',
                                  '{"version": 1, "topics": [{"name": "a"}], "configured": []}',
                                  '{"version": "one", "topics": [], "configured": []}', "[1, 2]"])
def test_a_damaged_file_is_ignored_and_left_alone(tmp_path, body, caplog):
    path = tmp_path / "queries.json"
    path.write_text(body)
    assert QueriesFile(path).load() is None
    assert "ignoring saved queries" in caplog.text
    assert path.read_text() == body


def test_a_newer_file_stops_the_start_untouched(tmp_path):
    path = tmp_path / "queries.json"
    body = json.dumps({"version": 7, "written_by": "3.0", "topics": [FISH], "configured": [FISH]})
    path.write_text(body)
    with pytest.raises(NewerFileError, match="queries.json.*version 7"):
        QueriesFile(path).load()
    assert path.read_text() == body
