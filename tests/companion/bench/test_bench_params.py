"""`merlion bench params` end to end, very short: every PARAM_SET is echoed and the figures add up (speed is not
asserted); a count that is not positive is a one-line usage error."""

from __future__ import annotations

import json

import pytest

from tests.conftest import run_merlion


@pytest.mark.slow
def test_every_param_set_is_echoed_and_the_round_trip_is_reported() -> None:
    done = run_merlion("bench", "params", "--count", "4", "--encoder", "visual", "--json", timeout=180)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["count"] == result["answered"] == 4
    assert 0 < result["p50_ms"] <= result["p95_ms"] <= result["max_ms"]
    assert result["encoder"] == "visual"
    assert "4/4 answered" in done.stdout


def test_a_count_of_zero_is_refused() -> None:
    done = run_merlion("bench", "params", "--count", "0", timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == "merlion: error: --count 0: must be positive"
