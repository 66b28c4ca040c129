"""``merlion bench surface`` end to end as a user runs it (a small, fast configuration)."""

from __future__ import annotations

import json

from tests.conftest import run_merlion


def test_bench_surface_reports_efficiency_and_time():
    proc = run_merlion("bench", "surface", "--frames", "2", "--budget", "20000", "--json", timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    push = result["push"]
    assert push["intact"] and push["captures_received"] == 2
    assert 0.85 < push["push_efficiency"] <= result["limit_encapsulated_data"] < result["limit_reference"]
    assert result["limit_encapsulated_data"] == round(253 / (10 + 2 + 253 + 2), 4)  # header, seqnr, data, CRC
    assert abs(push["of_limit"] - push["push_efficiency"] / (253 / 267)) < 0.001
    # every push byte on the wire is the protocol's own (marker, handshake, chunks): nothing sent twice
    assert abs(push["push_efficiency"] - push["floor_for_these_sizes"]) < 0.005
    assert push["seconds_to_surface"] > 0
    assert result["pull"] == {"frames": 2, "intact": 2, "seconds_to_surface": result["pull"]["seconds_to_surface"]}


def test_bench_surface_bad_source_is_one_line():
    proc = run_merlion("bench", "surface", "--source", "/nonexistent/video.mp4", timeout=60)
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines()[-1].startswith("merlion: error: source /nonexistent/video.mp4")


def test_bench_surface_gallery_fills_every_cap_and_reports_the_loops_share():
    proc = run_merlion("bench", "surface", "--gallery", "1", "--json", timeout=180)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])["gallery"]
    assert (result["captures"], result["summary"], result["archived"], result["dives"]) == (12288, 8192, 4096, 256)
    assert result["last_state_on_disk"] and result["loop_changes"] > 0 and result["rewrites"] >= 1
    assert 0 <= result["loop_share_writing"] <= result["loop_share_busy"] <= 1
