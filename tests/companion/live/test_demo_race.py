"""Two `merlion demo` on one --out at (nearly) the same time, as real processes: one runs, the other stops with one
line naming it (exit 2) having moved and written nothing, and the earlier run is moved aside once, whole.

Before, the store lock was taken only once the demo's companion started, seconds after the earlier run had been
moved aside and the simulator and surface tool spawned: the second demo moved the first one's fresh output aside
too (or failed to move what was already gone), and both surface tools and log files wrote into one folder until
the second demo's companion was refused."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.companion.live.test_demo_fresh import earlier_run
from tests.conftest import REPO

ARGS = ("--duration", "4", "--source", "synthetic://dive?seconds=2", "--tau-ss", "0.1", "--encoder", "visual")


def _demo(out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "companion", "demo", "--out", str(out), *ARGS], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _check(tmp_path: Path, out: Path, first: subprocess.Popen, second: subprocess.Popen) -> None:
    done = {p: p.communicate(timeout=300) for p in (first, second)}
    (winner,) = [p for p in done if p.returncode == 0] or [None]
    assert winner is not None, {p.returncode: d for p, d in done.items()}
    (loser,) = [p for p in done if p is not winner]
    stdout, stderr = done[loser]
    assert loser.returncode == 2, (stdout, stderr)
    lines = [x for x in stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: store {out / 'store'}: in use by pid "
                                                   f"{winner.pid} "), stderr
    assert stdout == "", "the refused demo said it moved something"
    (moved,) = tmp_path.glob("demo.previous-*")  # the earlier run, moved aside once, whole
    assert json.loads((moved / "report.json").read_text()) == {"frames_seen": 999}
    assert json.loads((moved / "store" / "summary.json").read_text()) == {"summary": [0, 1, 2, 3, 4, 5]}
    assert done[winner][0].splitlines()[0].endswith(f"was moved to {moved}")
    report = json.loads((out / "report.json").read_text())
    store = json.loads((out / "store" / "summary.json").read_text())
    assert report["summary"] == store["summary"] and report["frames_seen"] < 999
    for name in ("sim-vehicle.log", "surface.log"):
        assert (out / "logs" / name).is_file()
    assert "in use by" not in (out / "logs" / "surface.log").read_text()


@pytest.mark.slow
def test_two_demos_started_at_once_do_not_move_or_write_over_each_other(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    earlier_run(out)
    first, second = _demo(out), _demo(out)
    _check(tmp_path, out, first, second)

