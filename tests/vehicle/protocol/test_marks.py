"""The marks file's format (vehicle/protocol/marks.py): what the vehicle accepts, and a refusal naming the problem."""

from __future__ import annotations

import json

import pytest

from vehicle.protocol.marks import MARKS_MAX, format_marks, parse_marks


def test_parse_marks_accepts_the_format_and_drops_repeats():
    assert parse_marks(b'{"like": [5, 3, 5], "unlike": [7]}') == ([5, 3], [7])
    assert parse_marks(b'{"like": []}') == ([], [])


@pytest.mark.parametrize("data, says", [
    (b"not json", "not JSON"),
    (b"[1, 2]", "must be an object"),
    (b'{"like": [1], "maybe": [2]}', "unknown key 'maybe'"),
    (b'{"like": [-1]}', "like must be a list of image indices"),
    (b'{"unlike": [1.5]}', "unlike must be a list"),
    (b'{"like": [true]}', "like must be a list"),
    (b'{"like": "3"}', "like must be a list"),
    (b'{"like": [4], "unlike": [4]}', "image 4 is both like and unlike"),
    (json.dumps({"like": list(range(MARKS_MAX + 1))}).encode(), "more than"),
    (b" " * 5000, "bytes, more than"),
])
def test_parse_marks_refuses_bad_files_naming_the_problem(data, says):
    with pytest.raises(ValueError, match=says):
        parse_marks(data)


def test_format_marks_round_trips_through_parse_marks():
    assert parse_marks(format_marks([9, 2], [4])) == ([9, 2], [4])
