"""A second `merlion demo` starts fresh (issue 25): the earlier run is moved aside, never resumed silently nor lost."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.live.demo import set_aside_previous_run
from tests.conftest import run_merlion


def earlier_run(out: Path) -> None:
    (out / "store").mkdir(parents=True)
    (out / "store" / "summary.json").write_text('{"summary": [0, 1, 2, 3, 4, 5]}')
    (out / "report.json").write_text('{"frames_seen": 999}')


def test_an_earlier_run_is_moved_aside_whole_and_an_empty_folder_is_left_alone(tmp_path: Path) -> None:
    out = tmp_path / "merlion-demo"
    out.mkdir()
    assert set_aside_previous_run(out) is None and out.is_dir()  # nothing there: nothing to move
    earlier_run(out)
    moved = set_aside_previous_run(out)
    assert moved is not None and moved.parent == tmp_path and moved.name.startswith("merlion-demo.previous-")
    assert not out.exists()
    assert json.loads((moved / "store" / "summary.json").read_text())["summary"] == [0, 1, 2, 3, 4, 5]
    earlier_run(out)
    again = set_aside_previous_run(out)  # a second one in the same second gets its own name
    assert again is not None and again != moved and (again / "report.json").is_file() and moved.is_dir()


@pytest.mark.slow
def test_a_second_demo_starts_fresh_and_says_where_the_first_went(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    earlier_run(out)
    done = run_merlion("demo", "--duration", "3", "--out", str(out), "--source", "synthetic://dive?seconds=2",
                       "--tau-ss", "0.1", "--encoder", "visual", timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    (moved,) = tmp_path.glob("demo.previous-*")
    assert done.stdout.splitlines()[0] == (f"merlion demo: starting fresh; the earlier run in {out} was moved to "
                                           f"{moved}")
    assert json.loads((moved / "report.json").read_text()) == {"frames_seen": 999}
    report = json.loads((out / "report.json").read_text())
    assert report["frames_seen"] < 999 and report["summary_added"] == len(report["summary"]) + report["summary_removed"]
