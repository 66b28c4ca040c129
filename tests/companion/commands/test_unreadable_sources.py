"""A file or folder source that cannot be read at start fails at start, in `merlion run` and `merlion demo`: one
line naming the path and why, exit 2, nothing started (a camera can come back, a file cannot; both used to retry
or run the whole duration and exit 0)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.conftest import run_merlion, shared_file


def _truncated_video(tmp_path: Path) -> Path:
    whole = shared_file("survey/survey_480x270.mp4").read_bytes()  # its moov atom is after the data
    path = tmp_path / "trunc.mp4"
    path.write_bytes(whole[: len(whole) // 4])
    return path


def _nested_folder(tmp_path: Path) -> Path:
    top = tmp_path / "dive"
    (top / "images").mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(top / "images" / f"{i}.jpg"), np.full((48, 64, 3), 40 * i, np.uint8))
    (top / "labels.csv").write_text("file,label\n")
    return top


CASES = {
    "missing file": (lambda t: t / "nonexist.mp4", "{p}: no such file or folder"),
    "truncated video": (_truncated_video, "{p}: cannot be opened as a video"),
    "folder with its images one level down": (_nested_folder, "{p}: no images in {p} ({p}/images has 3)"),
}


@pytest.mark.parametrize("command", ["run", "demo"])
@pytest.mark.parametrize("case", list(CASES))
def test_an_unreadable_file_or_folder_source_fails_at_start(tmp_path: Path, command: str, case: str) -> None:
    make, message = CASES[case]
    path = make(tmp_path)
    out = tmp_path / "out"
    extra = ["--store", str(out), "--mavlink", "none"] if command == "run" else ["--out", str(out)]
    done = run_merlion(command, "--source", str(path), "--duration", "20", *extra, timeout=60)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: --source {message.format(p=path)}"), lines
    assert not out.exists(), "nothing started, nothing written"
