"""``merlion bench link --clients``: the many-clients stress as a user runs it, and its argument checks."""

from __future__ import annotations

import json

import pytest

from tests.conftest import run_merlion


@pytest.mark.slow
def test_bench_link_clients_reports_corruption_and_stalls():
    result = run_merlion("bench", "link", "--clients", "2", "--duration", "3", "--json", timeout=180)
    assert result.returncode == 0, result.stderr
    (run,) = json.loads(result.stdout.strip().splitlines()[-1])["stress"]
    assert run["clients"] == 2 and run["errors"] == [] and len(run["corrupted_by_client"]) == 2
    assert run["corrupted"] == 0 and min(run["received_by_client"]) > 100
    assert run["downloads"] > 0 and run["mismatched"] == 0 and run["autopilot_lost"] == 0
    assert run["refused_uploads"] and all(a.startswith("nak") for a in run["refused_uploads"])
    # refused by the app's own handler, called as the downlink calls it (it once failed on its signature instead)
    assert "refused: queries refused by the app (1 topic(s))" in result.stderr
    assert "positional argument" not in result.stderr
    assert 0 < run["rx_longest_ms"] and 0 <= run["rx_longest_cpu_ms"] <= run["rx_longest_ms"]
    assert "bench link: 2 client(s)" in result.stdout


@pytest.mark.parametrize("args, message", [
    (("--clients", "0"), "--clients 0: client counts must be between 1 and 16"),
    (("--clients", "two"), "--clients two: expected whole numbers"),
    (("--clients", "1", "--duration", "-3"), "--duration -3.0: must be a positive number"),
    ((), "give a LOG.tlog to replay, or --clients N"),
    (("--flood", "2"), "--flood 2.0: seconds per phase must be between 5 and 600"),
    (("--flood", "10", "--flood-rate", "0"), "--flood-rate 0.0: datagrams per second must be between 1"),
    (("--flood", "10", "--flood-ids", "300"), "--flood-ids 300: must be between 1 and 240"),
    (("--live",), "bench link: --live goes with --flood S"),
])
def test_bench_link_bad_arguments_are_one_line(args, message):
    result = run_merlion("bench", "link", *args, timeout=60)
    assert result.returncode == 2 and result.stderr.strip().startswith("merlion: error:")
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1
