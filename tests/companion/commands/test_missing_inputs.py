"""A missing input file is bad input, like a bad option: exit 2 and one line naming the path, in every command
(a helper found nine that exited 1)."""

from __future__ import annotations

import pytest

from tests.conftest import run_merlion, shared_file

CASES = {
    "eval labels": (["eval", "labels", "--labels", "{x}/labels.csv", "--summary", "3"], "{x}/labels.csv: no such file"),
    "eval srum": (["eval", "srum", "--labels", "{x}/labels.csv", "--humans", "{x}/humans.csv", "--summary", "3"],
                  "{x}/"),
    "eval auroc": (["eval", "auroc", "{x}/dive.mp4", "--labels", "{x}/labels.csv"], "{x}/labels.csv: no such file"),
    "eval compare": (["eval", "compare", "{x}/dive.mp4", "--labels", "{survey_labels}"],
                     "{x}/dive.mp4: no such video file"),
    "eval table": (["eval", "table", "--data", "{x}/srum"], "{x}/srum: SRUM data folder not found"),
    "eval auroc --data": (["eval", "auroc", "--data", "{x}", "--encoder", "visual"],
                          "{x}: not the shared data folder"),
    "replay-vehicle": (["replay-vehicle", "{x}/dive.tlog", "--connect", "udpout:127.0.0.1:9"],
                       "{x}/dive.tlog: no such telemetry log"),
    "bench link": (["bench", "link", "{x}/dive.tlog"], "{x}/dive.tlog: no such telemetry log"),
    "sim-vehicle --profile": (["sim-vehicle", "--profile", "{x}/dive.yaml", "--connect", "udpout:127.0.0.1:9"],
                              "{x}/dive.yaml: no such dive profile"),
    "archive": (["archive", "{x}/videos", "--out", "{x}/out"], "{x}/videos: no such file or folder"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_missing_input_is_exit_2_and_one_line_naming_it(tmp_path, name):
    args, message = CASES[name]
    fill = {"x": str(tmp_path), "survey_labels": str(shared_file("survey/survey_480x270_labels.csv"))}
    proc = run_merlion(*[a.format(**fill) for a in args], timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith(f"merlion: error: {message.format(**fill)}"), proc.stderr
    assert not any(line.startswith("Traceback") for line in lines)


def test_marks_that_contradict_each_other_are_refused_before_anything_is_sent():
    proc = run_merlion("surface-mark", "--like", "1", "--unlike", "1", "--connect", "udpout:127.0.0.1:9",
                       timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == "merlion: error: marks file: image 1 is both like and unlike"
