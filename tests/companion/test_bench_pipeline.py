"""`merlion bench pipeline --json` runs end to end and ends with the agreed JSON object (speeds are not asserted)."""

from __future__ import annotations

import json

from tests.conftest import run_merlion, shared_file


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


def test_bench_pipeline_bad_source_is_one_line(tmp_path):
    proc = run_merlion("bench", "pipeline", str(tmp_path / "nope.mp4"), "--encoder", "visual")
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines()[-1].startswith("merlion: error:")
