"""marks.json in the store: saved crash-safely, read back, damaged files ignored, newer files refused untouched."""

from __future__ import annotations

import json

import pytest

from companion.storage.marks_file import MarksFile, SavedMarks
from companion.storage.versioned import NewerFileError


def test_saved_marks_come_back(tmp_path):
    file = MarksFile(tmp_path / "store" / "marks.json", version="9.9")
    assert not file.load()
    file.save(SavedMarks([3, 5], [7], "underwater image of a fish"))
    assert file.load() == SavedMarks([3, 5], [7], "underwater image of a fish")
    assert json.loads(file.path.read_text())["written_by"] == "9.9"
    file.clear()
    assert not file.load()


@pytest.mark.parametrize("text", ["{not json", '{"version": 1, "like": [-2]}', '{"version": 1, "like": "3"}',
                                  '{"like": [1]}', '{"version": 1, "query": 4}'])
def test_a_damaged_file_means_no_marks(tmp_path, text):
    path = tmp_path / "marks.json"
    path.write_text(text)
    assert MarksFile(path).load() == SavedMarks()
    assert path.read_text() == text


def test_a_newer_file_stops_the_start_and_stays(tmp_path):
    path = tmp_path / "marks.json"
    text = '{"version": 7, "written_by": "42.0", "like": [1]}'
    path.write_text(text)
    with pytest.raises(NewerFileError, match="42.0"):
        MarksFile(path, version="1.0").load()
    assert path.read_text() == text


def test_each_topics_query_is_kept_and_an_older_file_answers_with_its_one_query(tmp_path):
    file = MarksFile(tmp_path / "marks.json", version="9.9")
    marks = SavedMarks([3], [7], "underwater image with fish",
                       {"fish": "underwater image with fish", "coral": "underwater image of a coral reef"})
    file.save(marks)
    assert file.load() == marks
    assert marks.query_of("coral") == "underwater image of a coral reef" and marks.query_of("wreck") == ""

    file.path.write_text('{"version": 1, "query": "underwater image with fish", "like": [3]}')  # before topics
    older = file.load()
    assert older == SavedMarks([3], [], "underwater image with fish")
    assert older.query_of("main") == older.query_of("coral") == "underwater image with fish"

    file.path.write_text('{"version": 1, "topics": {"fish": 4}, "like": [3]}')
    assert file.load() == SavedMarks()  # damaged: ignored
