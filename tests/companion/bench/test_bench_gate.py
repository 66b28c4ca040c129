"""`merlion bench gate` on the survey video, a 1-s ROV clip and that clip looped: the gated summary covers the same
segments as the ungated one and is within 0.02 SRUM of it while encoding fewer frames (issue 25 item 3), and the
command prints the comparison."""

from __future__ import annotations

import json

import pytest

from companion.bench.gate_bench import compare_case, default_cases
from companion.config import load_config
from companion.vision.encoders.factory import make_encoder
from tests.conftest import run_merlion, shared_file


@pytest.fixture(scope="module")
def survey_10fps():
    data = shared_file("survey/survey_480x270.mp4").parent.parent
    (case,) = [c for c in default_cases(data) if c.name == "survey 10 fps"]
    return case


@pytest.mark.slow
def test_the_gated_survey_summary_covers_the_ungated_segments_within_002_srum(survey_10fps):
    cfg = load_config(None, overrides={"encoder": {"name": "imagenet"}, "queries": {"tau_ss": 0.0}})
    row = compare_case(cfg, survey_10fps, make_encoder(cfg.encoder))
    gated, ungated = row["gated"], row["ungated"]
    assert ungated["encoder_calls"] == 93 and gated["encoder_calls"] <= 56  # the gate still saves 4 calls in 10
    assert gated["segments"] == ungated["segments"], row
    assert len(gated["segments"]) >= 4 and row["segments_total"] == 5
    assert abs(row["srum_delta"]) <= 0.02, row


@pytest.fixture(scope="module")
def imagenet_cfg_encoder():
    cfg = load_config(None, overrides={"encoder": {"name": "imagenet"}, "queries": {"tau_ss": 0.0}})
    return cfg, make_encoder(cfg.encoder)


@pytest.mark.slow
@pytest.mark.parametrize("name, most_calls", [("ROV clip 2 30 fps", 16), ("ROV clip 1 looped x6", 36)])
def test_a_short_clip_and_a_loop_keep_the_ungated_segments(imagenet_cfg_encoder, name, most_calls):
    """A 1-s clip (16 frames) and the same clip looped six times: a gate that only samples by time encoded 2 of 16
    and 11 of 60 frames and covered 2 of 5 slices where the ungated summary covered 5; the share rule
    (``gate.max_gap_share``) encodes short footage densely enough to keep every slice (the 16 frames all; the loop's
    first round all, then fewer each round)."""
    shared_file("rov_clips")
    cfg, encoder = imagenet_cfg_encoder
    (case,) = [c for c in default_cases(shared_file("rov_clips").parent) if c.name == name]
    row = compare_case(cfg, case, encoder)
    gated, ungated = row["gated"], row["ungated"]
    assert ungated["encoder_calls"] == row["frames"] and gated["encoder_calls"] <= most_calls, row
    assert len(ungated["segments"]) == 5 and gated["segments"] == ungated["segments"], row
    assert abs(row["srum_delta"]) <= 0.02, row


def test_the_command_prints_the_table_and_json(tmp_path):
    data = shared_file("survey/survey_480x270.mp4").parent.parent
    proc = run_merlion("bench", "gate", "--data", str(data), "--case", "ROV clip 1 30", "--encoder", "visual",
                       "--json", timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[0].startswith("gate: difference > 8, max gap 0.5 s, share 0.05; tau_ss 0; K 6; encoder visual")
    assert lines[2].startswith("ROV clip 1 30 fps")
    (row,) = json.loads(lines[-1])["rows"]
    assert row["case"] == "ROV clip 1 30 fps" and row["ungated"]["encoder_calls"] == row["frames"]
    proc = run_merlion("bench", "gate", "--data", str(data), "--case", "no such video", timeout=60)
    assert proc.returncode == 2 and "no such case" in proc.stderr
