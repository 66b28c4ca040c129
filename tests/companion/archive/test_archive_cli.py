"""`merlion archive` refuses bad input with one line naming what is wrong, before any Ray work starts."""

from __future__ import annotations

import importlib.util

import pytest

from tests.conftest import run_merlion, shared_file


def error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.startswith("merlion: error:")]
    assert len(lines) == 1, stderr
    return lines[0]


def test_missing_source_and_bad_options_are_one_line_errors(tmp_path):
    proc = run_merlion("archive", str(tmp_path / "nowhere.mp4"), "--out", str(tmp_path / "out"))
    assert proc.returncode != 0
    assert "nowhere.mp4: no such file or folder" in error_line(proc.stderr)
    video = shared_file("survey/survey_480x270.mp4")
    proc = run_merlion("archive", str(video), "--out", str(tmp_path / "out"), "--workers", "0")
    assert proc.returncode == 2 and "--workers must be at least 1, got 0" in error_line(proc.stderr)
    mapping = tmp_path / "map.csv"
    mapping.write_text("video,log\nx.mp4,a.tlog\n")
    proc = run_merlion("archive", str(video), "--out", str(tmp_path / "out"), "--mapping", str(mapping))
    assert proc.returncode != 0 and "map.csv: the mapping file needs the header video,tlog,offset_s" in \
        error_line(proc.stderr)
    assert not (tmp_path / "out" / "manifest.json").exists()


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray not installed (the archive extra)")
# local Ray (ray.init without an address) joins any Ray instance running on this machine: never beside
# test_archive_ray's cluster on another xdist worker (tests/conftest.py)
@pytest.mark.slow
@pytest.mark.xdist_group("ray")
def test_gpus_asked_where_there_are_none_is_refused_not_a_hang(tmp_path):
    proc = run_merlion("archive", str(shared_file("survey/survey_480x270.mp4")), "--out", str(tmp_path / "out"),
                       "--workers", "1", "--gpus-per-task", "1", "--encoder", "visual", timeout=120)
    assert proc.returncode != 0
    assert "--gpus-per-task 1: no node of this Ray cluster has that many (GPU per node at most 0)" in \
        error_line(proc.stderr)
