"""`merlion bench pipeline --json` runs end to end and ends with the agreed JSON object (speeds are not asserted)."""

from __future__ import annotations

import json
import re

import open_clip
import pytest
import torch

from tests.conftest import run_merlion, shared_file

SMALL = "ViT-S-32-alt"


def test_bench_pipeline_json_last_line():
    proc = run_merlion("bench", "pipeline", str(shared_file("survey/survey_480x270.mp4")), "--encoder", "visual",
                       "--fps", "5", "--frames", "60", "--batch", "4", "--json")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    result = json.loads(lines[-1])
    for key in ("end_to_end_fps", "encoder_fps", "sampler_ms_k6", "sampler_ms_k64", "peak_rss_mb"):
        assert isinstance(result[key], (int, float)) and result[key] > 0, key
    assert result["frames"] == 60 and result["batch"] == 4  # 47 frames at 5 fps: looped past the end
    assert "end to end" in proc.stdout
    assert result["paper_loop_frames"] == 32 and result["paper_loop_fps"] > 0  # the default baseline ran
    assert result["speedup_vs_paper_loop"] == pytest.approx(result["end_to_end_fps"] / result["paper_loop_fps"],
                                                            rel=0.01)
    assert "x the paper's loop" in proc.stdout
    assert set(result["cpu_ms_per_frame"]) == {"end_to_end", "video", "encoder", "paper_loop"}
    assert all(v > 0 for v in result["cpu_ms_per_frame"].values()) and result["cpu_speedup_vs_paper_loop"] > 0
    (cpu_line,) = [line for line in proc.stdout.splitlines() if line.startswith("CPU time")]
    vs = result["cpu_speedup_vs_paper_loop"]  # paper loop's CPU per frame over ours: below 1, ours takes more
    said = re.search(r"\(([\d.]+) x (less|more) than the paper's loop\)", cpu_line)
    assert said, cpu_line
    assert said[2] == ("less" if vs >= 1 else "more") or abs(vs - 1) < 0.01, (cpu_line, vs)
    assert float(said[1]) == pytest.approx(vs if said[2] == "less" else 1 / vs, abs=0.011), (cpu_line, vs)


@pytest.mark.slow
def test_paper_loop_baseline_runs_clip_in_fp32_whatever_the_run_uses(tmp_path):
    """An int8 run is compared with the paper's fp32 loop (a second model built for it), on the same frames."""
    torch.manual_seed(0)
    ckpt = tmp_path / "small.pt"
    torch.save(open_clip.create_model(SMALL, pretrained=None).state_dict(), ckpt)
    proc = run_merlion("bench", "pipeline", str(shared_file("survey/survey_480x270.mp4")), "--encoder", "clip",
                       "--model", SMALL, "--weights", str(ckpt), "--precision", "int8", "--fps", "5",
                       "--frames", "8", "--batch", "4", "--paper-frames", "3", "--json")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["encoder"]["precision"] == "int8" and result["paper_loop_precision"] == "fp32"
    assert result["paper_loop_frames"] == 3 and result["paper_loop_fps"] > 0


def test_paper_loop_can_be_skipped_and_bad_counts_are_refused():
    video = str(shared_file("survey/survey_480x270.mp4"))
    proc = run_merlion("bench", "pipeline", video, "--encoder", "visual", "--frames", "8", "--paper-frames", "0",
                       "--json")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["paper_loop_fps"] is None and result["speedup_vs_paper_loop"] is None
    proc = run_merlion("bench", "pipeline", video, "--encoder", "visual", "--paper-frames", "-1")
    assert proc.returncode == 2 and "--paper-frames" in proc.stderr.strip().splitlines()[-1]


def test_bench_pipeline_bad_source_is_one_line(tmp_path):
    proc = run_merlion("bench", "pipeline", str(tmp_path / "nope.mp4"), "--encoder", "visual")
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines()[-1].startswith("merlion: error:")


def test_bench_pipeline_reports_the_video_rate_and_the_gate():
    """video_fps counts every source frame (skipped ones included), encoder_calls the frames encoded; gate none
    encodes all of them; memory at load and at the end are reported."""
    video = str(shared_file("survey/survey_480x270.mp4"))
    results = {}
    for gate in ("difference", "none"):
        proc = run_merlion("bench", "pipeline", video, "--encoder", "visual", "--frames", "40", "--batch", "4",
                           "--paper-frames", "4", "--gate", gate, "--json")
        assert proc.returncode == 0, proc.stderr
        results[gate] = json.loads(proc.stdout.strip().splitlines()[-1])
    gated, ungated = results["difference"], results["none"]
    for r in (gated, ungated):
        assert r["frames"] == 40 and r["video_fps"] > 0 and r["end_to_end_fps"] > 0 and r["encoder_fps"] > 0
        assert r["peak_rss_mb"] >= r["load_peak_rss_mb"] > 0 and r["steady_rss_mb"] > 0
        assert r["video_speedup_vs_paper_loop"] == pytest.approx(r["video_fps"] / r["paper_loop_fps"], rel=0.01)
    assert gated["gate"]["mode"] == "difference" and 0 < gated["encoder_calls"] < 40
    assert ungated["gate"]["mode"] == "none" and ungated["encoder_calls"] == 40
    assert ungated["video_fps"] == pytest.approx(ungated["end_to_end_fps"], rel=0.01)
