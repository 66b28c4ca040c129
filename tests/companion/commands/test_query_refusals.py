"""Queries that cannot mean anything are refused in the user's words, exit 2, before any work: an empty one
(it used to read "String should have at least 1 character (got '')" or "query: the positive query is empty"),
and a negative that is the positive itself (it used to score every image 0.5 in silence). An existing file given
to `merlion export` is not "no such folder"."""

from __future__ import annotations

import pytest

from tests.conftest import run_merlion, shared_file

STILL = "deepfish/images/7117_Caranx_sexfasciatus_juvenile_f000006.jpg"
EMPTY = "merlion: error: --query: empty (name a thing to look for, e.g. 'fish')"
SAME = ("the same as the positive query, so every frame would score 0.5; give a different negative or leave it "
        "out")


@pytest.mark.parametrize("query", ["", "   "])
@pytest.mark.parametrize("command", ["summarize", "score"])
def test_an_empty_query_is_refused_in_one_line(tmp_path, command, query):
    out = ["--out", str(tmp_path / "out")] if command == "summarize" else []
    proc = run_merlion(command, str(shared_file(STILL)), *out, "--query", query, "--encoder", "visual")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [EMPTY]


@pytest.mark.parametrize(("args", "line"), [
    (["--query", "fish", "--negative", " Fish "], f"merlion: error: --negative ' Fish ': {SAME}"),
    (["--topic", "a=fish;fish"], f"merlion: error: --topic a: negative 'fish': {SAME}"),
    (["--query", "fish", "--negative", ""],
     "merlion: error: --negative: empty (name what the wanted frames do not show, or leave it out)"),
])
def test_a_negative_the_same_as_the_positive_or_empty_is_refused(args, line):
    proc = run_merlion("score", str(shared_file(STILL)), *args, "--encoder", "visual")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [line]


def test_export_of_a_file_says_it_is_not_a_folder(tmp_path):
    video = shared_file("survey/survey_480x270.mp4")
    proc = run_merlion("export", str(video), "--format", "csv", "--out", str(tmp_path / "x.csv"))
    assert proc.returncode == 2 and not (tmp_path / "x.csv").exists()
    assert proc.stderr.strip().splitlines() == [
        f"merlion: error: {video}: a file, not a store, summary or campaign folder (give the folder that merlion "
        f"summarize, archive or run wrote)"]
