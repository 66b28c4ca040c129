"""`merlion bench soak` end to end, very short: the figures are there and add up (speed is not asserted)."""

from __future__ import annotations

import json

import pytest

from tests.conftest import run_merlion


@pytest.mark.slow
def test_soak_reports_fps_drops_memory_and_latency_as_json() -> None:
    done = run_merlion("bench", "soak", "--minutes", "0.1", "--fps", "10", "--encoder", "visual", "--json",
                       timeout=180)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    for key in ("scored_fps", "frames_dropped", "peak_rss_mb", "rss_growth_pct", "latency_p50_s", "latency_p95_s"):
        assert key in result
    assert result["frames_seen"] >= result["frames_scored"] > 0
    assert result["captures_received"] > 0 and 0 < result["latency_p50_s"] <= result["latency_p95_s"]
    assert result["peak_rss_mb"] >= result["rss_end_mb"] > 0
    assert result["gate"] == "difference"  # the configuration's default
    assert result["frames_seen"] >= result["frames_scored"] + result["frames_skipped"]
    assert result["encoder_fps"] > 0
    assert abs(result["scored_vs_encoder"] - result["scored_fps"] / result["encoder_fps"]) < 0.01


@pytest.mark.slow
def test_soak_without_the_gate_scores_every_frame_it_takes() -> None:
    done = run_merlion("bench", "soak", "--duration", "5", "--fps", "8", "--encoder", "visual", "--gate", "none",
                       "--json", timeout=180)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["gate"] == "none" and result["frames_skipped"] == 0 and result["frames_scored"] > 0
    assert "x that" in done.stdout


@pytest.mark.slow
def test_soak_from_a_rendered_clip_reports_the_decode_rate_beside_the_drops() -> None:
    """`--clip WxH`: the generated dive as an H.264 file played in real time (skipped without ffmpeg, which
    .ci/run installs); the decode rate is measured beside the drops, and the gate runs on the capture thread."""
    import shutil

    if shutil.which("ffmpeg") is None:
        pytest.skip("ffmpeg is not installed")
    done = run_merlion("bench", "soak", "--clip", "320x180", "--fps", "30", "--duration", "8", "--encoder",
                       "visual", "--json", timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["source"] == "320x180 file" and result["frames_seen"] > 0
    assert result["decode_fps"] > 0 and abs(result["decode_vs_source"] - result["decode_fps"] / 30) < 0.01
    assert result["admit_ms"] is not None and result["admit_ms"] > 0  # gated and downscaled on the capture thread
    assert 0 <= result["dropped_after_warmup"] <= result["frames_dropped"]
    assert abs(result["dropped_pct"] - 100 * result["frames_dropped"] / result["frames_seen"]) < 0.01
    assert "decode            " in done.stdout and "x the source's 30 fps" in done.stdout
    bad = run_merlion("bench", "soak", "--clip", "1920by1080", timeout=60)
    assert bad.returncode == 2 and bad.stderr.strip().startswith("merlion: error: bench soak --clip")
