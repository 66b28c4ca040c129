"""`merlion bench archive --json` runs end to end on local Ray; the table's ratios come from its own runs."""

from __future__ import annotations

import importlib.util
import json

import pytest

from companion.bench.archive_bench import ArchiveBench, WorkerRun
from tests.conftest import run_merlion, shared_file


def test_scaling_and_estimate_come_from_the_runs():
    bench = ArchiveBench([WorkerRun(1, 8, 160, 60.0, 40.0, 16.0, 1.0, 1),
                          WorkerRun(2, 8, 160, 40.0, 24.0, 18.0, 1.0, 2)], "imagenet")
    assert bench.scaling() == pytest.approx(1.5) and bench.scaling(span=True) == pytest.approx(40.0 / 24.0)
    assert bench.runs[0].our_cores == pytest.approx(0.4)
    table = bench.table()
    assert "1.50x whole run, 1.67x task span (efficiency 83%)" in table
    assert "2.00 CPU s per video" in table and "N x 30.0 videos/min" in table


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray not installed (the archive extra)")
# local Ray (ray.init without an address) joins any Ray instance running on this machine: never beside
# test_archive_ray's cluster on another xdist worker (tests/conftest.py)
@pytest.mark.slow
@pytest.mark.xdist_group("ray")
def test_bench_archive_json_last_line():
    proc = run_merlion("bench", "archive", str(shared_file("survey/survey_480x270.mp4")), "--encoder", "visual",
                       "--videos", "2", "--seconds", "1", "--workers", "1", "--json", timeout=180)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["encoder"] == "visual" and result["scaling"] is None  # one worker count: no ratio
    (run,) = result["runs"]
    assert run["workers"] == 1 and run["videos"] == 2 and run["frames"] == 10  # 1 s at 10 fps, kept at 5 fps
    assert run["encoder_loads"] == 1 and run["wall_s"] >= run["span_s"] > 0 and run["task_cpu_s"] > 0
    assert 0 <= run["machine_busy"] <= 1
