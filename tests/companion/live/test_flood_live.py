"""Issue 46 item 1 in the issue's own setup: the unsigned flood against the whole live companion, not the Downlink
alone. Real processes on loopback with one signing key: `merlion run` on a video file, `merlion sim-vehicle`
signing, a UDP hub as the vehicle's router (its own process), a signed ground station on it, and ~1,500 unsigned
datagrams/s from 200 made-up ids sent to the router (``companion/bench/flood_live_bench.py``; `merlion bench link
--flood 60 --live` runs the full minute, docs/vehicle.md gives its figures)."""

from __future__ import annotations

import pytest

from companion.bench.flood_live_bench import CAPTURE_EVERY_S, measure_live_flood

SECONDS = 12.0


@pytest.mark.slow
def test_captures_and_the_thumbnail_push_reach_the_signed_station_through_a_mixed_unsigned_flood():
    result = measure_live_flood(SECONDS, after_s=SECONDS / 2)
    before, flood, after = result["before"], result["flood"], result["after"]
    print(f"\n{result['flood_sent']} flood datagrams; before {before}\nflood {flood}\nafter {after}\n"
          f"answers after the quiet time: {result['answers_after_quiet']} (last {result['last_answer_after_flood_s']} s); "
          f"refusal lines in the companion's log: {result['companion_log_refusal_lines']}")
    assert result["flood_sent"] >= 0.5 * 1500 * SECONDS  # the flood really ran at (about) its pace
    steady = SECONDS / CAPTURE_EVERY_S
    assert before["captures_made"] >= 0.5 * steady and before["captures_received"] == before["captures_made"]
    assert flood["received_pct_of_before"] >= 60  # the issue: 42-56% reached the station
    assert flood["chunks"] > 0 and after["chunks"] > 0  # the push goes on (the issue: none during it and 30 s after)
    assert after["captures_received"] > 0
    assert flood["answers_to_flood"] > 0  # the strangers' reads are answered, within their slice,
    assert result["answers_after_quiet"] <= 0.05 * flood["answers_to_flood"]  # nearly none once they went quiet
    assert result["companion_log_refusal_lines"] <= 2 + SECONDS * 2 / 10  # not a line per made-up id (was ~200)

