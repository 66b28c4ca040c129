"""Plain progress lines off a terminal: one when the first batch is done, then one per ``every_s`` of the clock,
with the figures given last; and what ``summarize`` and ``score`` print on a stderr that is a pipe."""

from __future__ import annotations

import io

import cv2
import numpy as np

from companion.vision.progress_lines import ProgressLines
from tests.conftest import run_merlion, shared_file


def test_a_line_at_the_first_update_then_one_per_interval_with_the_figures():
    now = [100.0]
    out = io.StringIO()
    lines = ProgressLines("summarize", "frame", 660, every_s=10.0, stream=out, clock=lambda: now[0])
    lines.set_postfix(passed=0, held=0)
    lines.update(8)  # the first batch: said at once
    for _ in range(9):  # 9 s later: nothing more
        now[0] += 1.0
        lines.set_postfix(passed=3, held=2)
        lines.update(8)
    now[0] += 1.0
    lines.update(8)  # 10 s after the first line
    assert out.getvalue().splitlines() == ["summarize: 8/660 frames (1%), passed 0, held 0",
                                           "summarize: 88/660 frames (13%), passed 3, held 2"]
    count = ProgressLines("score", "image", None, stream=io.StringIO())
    count.update(1)
    assert count.line() == "score: 1 image"
    count.update(2)
    assert count.line() == "score: 3 images"


def test_summarize_and_score_say_they_are_working_when_stderr_is_a_pipe(tmp_path):
    proc = run_merlion("summarize", str(shared_file("survey/survey_480x270.mp4")), "--out", str(tmp_path / "out"),
                       "--encoder", "visual", "--fps", "2")
    assert proc.returncode == 0, proc.stderr
    said = [line for line in proc.stderr.splitlines() if line.startswith("summarize: ")]
    assert said and all("frames (" in line and ", passed " in line and ", held " in line for line in said), said
    assert "%|" not in proc.stderr  # no bar redrawn in place
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.full((48, 64, 3), 80, np.uint8))
    proc = run_merlion("score", str(image), str(image), "--encoder", "visual")
    assert proc.returncode == 0, proc.stderr
    assert "score: 1 image" in proc.stderr.splitlines()
