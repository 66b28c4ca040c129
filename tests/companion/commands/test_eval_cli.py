"""``merlion eval ...`` as a user runs it: real subprocesses, real data from ../shared/data."""

from __future__ import annotations

import json

import cv2
import pytest

from tests.conftest import REPO, run_merlion, shared_file


def test_table_json_reproduces_the_paper():
    data = shared_file("srum/powellscay_low.json").parent
    r = run_merlion("eval", "table", "--data", str(data), "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    table = json.loads(r.stdout)
    assert round(table["powellscay_low"]["Human"], 4) == 0.6562
    assert round(table["bonaire_moderate"]["ROST"], 3) == 0.364
    assert round(table["kralendijk_clear"]["MERLION"], 4) == 0.4227
    if data.resolve() == (REPO.parent / "shared" / "data" / "srum").resolve():
        text = run_merlion("eval", "table", timeout=120)  # the default: ../shared/data/srum beside the repo
    else:
        text = run_merlion("eval", "table", "--data", str(data), timeout=120)
    assert text.returncode == 0, text.stderr
    assert "truncated" in text.stdout and "mismatch" not in text.stdout


def test_table_without_data_is_a_one_line_error(tmp_path):
    r = run_merlion("eval", "table", "--data", str(tmp_path / "nowhere"))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "nowhere" in r.stderr and "--data" in r.stderr


def test_srum_of_the_papers_merlion_summary_and_relative_score(tmp_path):
    low = shared_file("srum/powellscay_low.json")
    r = run_merlion("eval", "srum", "--labels", str(low), "--summary", "743", "2051", "2185", "2647", "2661", "2996",
                    "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert round(out["srum"], 4) == 0.2446 and round(out["human"], 4) == 0.6562
    assert out["relative"] == pytest.approx(100 * out["srum"] / out["human"])
    # the same summary as a summary.json of 0-based source indices
    (tmp_path / "summary.json").write_text(json.dumps(
        {"source": "x", "encoder": {}, "params": {},
         "frames": [{"index": f - 1, "time_s": (f - 1) / 30, "score": 0.9, "file": ""} for f in
                    (743, 2051, 2185, 2647, 2661, 2996)]}))
    r2 = run_merlion("eval", "srum", "--labels", str(low), "--summary-json", str(tmp_path), "--json",
                     "--report", str(tmp_path / "rep"))
    assert r2.returncode == 0, r2.stderr
    assert json.loads(r2.stdout.splitlines()[0])["srum"] == pytest.approx(out["srum"])
    assert (tmp_path / "rep" / "index.html").is_file()
    bad = run_merlion("eval", "srum", "--labels", str(low), "--summary", "999999")
    assert bad.returncode == 1 and "frame 999999" in bad.stderr


def test_srum_with_a_csv_and_a_humans_file(tmp_path):
    (tmp_path / "l.csv").write_text("frame,labels\n" + "".join(f"{f},{'A' if f in (10, 100) else ''}\n"
                                                              for f in range(1, 201)))
    (tmp_path / "h.txt").write_text("100\n10\n")
    r = run_merlion("eval", "srum", "--labels", str(tmp_path / "l.csv"), "--humans", str(tmp_path / "h.txt"),
                    "--summary", "10", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    # against [100]: 0.5 + 0.5 e^-1; against [10]: 1 -> mean; humans score each other 0.5 + 0.5 e^-1
    assert out["srum"] == pytest.approx((0.5 + 0.5 * 0.36787944117 + 1) / 2)
    assert out["human"] == pytest.approx(0.5 + 0.5 * 0.36787944117)
    missing = run_merlion("eval", "srum", "--labels", str(tmp_path / "l.csv"), "--summary", "10")
    assert missing.returncode == 2 and "--humans" in missing.stderr


def test_labels_on_the_survey(tmp_path):
    csv = shared_file("survey/survey_480x270_labels.csv")
    r = run_merlion("eval", "labels", "--labels", str(csv), "--fps", "10", "--summary", "2", "20", "30", "47", "60",
                    "75", "--json", "--report", str(tmp_path / "rep"))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[0])
    assert out["precision"] == pytest.approx(4 / 6) and out["coverage"] == 1.0 and out["query"] == "fish"
    assert len(out["oracle"]) == 6 and 0 < out["srum_oracle"] <= 1
    assert "precision" in (tmp_path / "rep" / "index.html").read_text()


def test_auroc_of_the_visual_baseline_is_chance():
    video = shared_file("survey/survey_480x270.mp4")
    csv = shared_file("survey/survey_480x270_labels.csv")
    r = run_merlion("eval", "auroc", str(video), "--labels", str(csv), "--encoder", "visual", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["auroc"] == 0.5 and out["frames"] == 93 and out["positives"] == 60
    assert out["at_tau_ss"]["recall"] == 1.0 and out["at_tau_ss"]["false_pass"] == 1.0


def test_summarize_with_the_visual_baseline_then_evaluate_its_summary_json(tmp_path):
    video = shared_file("survey/survey_480x270.mp4")
    csv = shared_file("survey/survey_480x270_labels.csv")
    s = run_merlion("summarize", str(video), "--encoder", "visual", "--out", str(tmp_path / "sum"))
    assert s.returncode == 0, s.stderr
    doc = json.loads((tmp_path / "sum" / "summary.json").read_text())
    assert doc["encoder"] == "visual" and len(doc["frames"]) == 6
    assert all(f["score"] == 1.0 for f in doc["frames"])
    r = run_merlion("eval", "labels", "--labels", str(csv), "--fps", "10", "--summary-json",
                    str(tmp_path / "sum" / "summary.json"), "--json", "--report", str(tmp_path / "rep"),
                    "--video", str(video))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[0])
    assert out["frames"] == sorted(f["index"] + 1 for f in doc["frames"])
    page = (tmp_path / "rep" / "index.html").read_text()
    for png in ("summary_contact_sheet.png", "summary_score.png"):  # the score plot from re-scoring --video
        assert png in page and (tmp_path / "rep" / png).is_file()


@pytest.mark.slow
def test_compare_merlion_and_the_visual_baseline_on_the_survey(tmp_path):
    video = shared_file("survey/survey_480x270.mp4")
    csv = shared_file("survey/survey_480x270_labels.csv")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("source:\n  fps: 1\nencoder:\n  input_size: 224\n")  # 10 frames keep the test short
    r = run_merlion("eval", "compare", str(video), "--labels", str(csv), "--encoder", "imagenet", "--config",
                    str(cfg), "--no-scores", "--json", "--out", str(tmp_path / "runs"), "--report",
                    str(tmp_path / "rep"))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[0])
    merlion, baseline = out["runs"]["MERLION"], out["runs"]["visual baseline"]
    assert merlion["encoder"].startswith("imagenet") and baseline["encoder"] == "visual"
    # frames at 1 fps are 1, 11, 21, ...: the baseline keeps no-fish frames, the semantic filter drops them
    assert all((f - 1) % 10 == 0 for f in merlion["frames"] + baseline["frames"])
    assert merlion["precision"] > baseline["precision"]
    assert (tmp_path / "runs" / "merlion" / "summary.json").is_file()
    assert (tmp_path / "rep" / "visual_baseline_contact_sheet.png").is_file()


@pytest.mark.slow
def test_compare_shows_the_gated_summary_against_the_ungated_one(tmp_path):
    """With the frame gate on, MERLION also runs ungated on the same video and the gate's cost is reported."""
    video = shared_file("survey/survey_480x270.mp4")
    csv = shared_file("survey/survey_480x270_labels.csv")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("source:\n  fps: 5\nencoder:\n  input_size: 224\ngate:\n  mode: difference\n"
                   "  threshold: 6\n  max_gap_s: 1.0\n")
    r = run_merlion("eval", "compare", str(video), "--labels", str(csv), "--encoder", "imagenet", "--config",
                    str(cfg), "--no-scores", "--json", "--out", str(tmp_path / "runs"))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[0])
    gated, ungated = out["runs"]["MERLION"], out["runs"]["MERLION ungated"]
    assert ungated["frames_encoded"] == ungated["frames_seen"] == gated["frames_seen"]
    assert 0 < gated["frames_encoded"] < gated["frames_seen"]
    g = out["gate"]
    assert g["gate"] == {"mode": "difference", "threshold": 6.0, "max_gap_s": 1.0, "max_gap_share": 0.05}
    assert g["encoded_share"] == pytest.approx(gated["frames_encoded"] / gated["frames_seen"])
    assert 0.0 <= g["srum_gated_vs_ungated"] <= 1.0 and 0.0 <= g["srum_ungated_vs_gated"] <= 1.0
    assert g["precision_delta"] == pytest.approx(gated["precision"] - ungated["precision"], abs=1e-6)
    assert (tmp_path / "runs" / "merlion-ungated" / "summary.json").is_file()
    from companion.evaluation.compare import format_compare

    assert "SRUM gated vs ungated" in format_compare(out)  # what the command prints without --json


def test_table_reports_a_value_that_does_not_match(tmp_path):
    data = json.loads(shared_file("srum/powellscay_low.json").read_text())
    data["paper_table"]["ROST"] = 0.1111  # ours is 0.110907
    (tmp_path / "powellscay_low.json").write_text(json.dumps(data))
    r = run_merlion("eval", "table", "--data", str(tmp_path))
    assert r.returncode == 1
    assert "mismatch" in r.stdout and r.stderr.strip().endswith("0.110907 vs 0.1111")
    assert r.stderr.count("\n") == 1 and "powellscay_low ROST" in r.stderr


def test_auroc_refuses_labels_past_the_end_of_a_truncated_video(tmp_path):
    """The survey's 93 labels against its first 20 frames (a cut recording), and its own video with one label
    past its end: both used to score what decoded and exit 0."""
    video = shared_file("survey/survey_480x270.mp4")
    labels = shared_file("survey/survey_480x270_labels.csv")
    cap = cv2.VideoCapture(str(video))
    short = tmp_path / "cut.mp4"
    writer = cv2.VideoWriter(str(short), cv2.VideoWriter_fourcc(*"mp4v"), 10, (480, 270))
    for _ in range(20):
        ok, frame = cap.read()
        assert ok
        writer.write(frame)
    writer.release()
    cap.release()
    extra = tmp_path / "extra.csv"
    extra.write_text(labels.read_text().rstrip("\n") + "\n4999,9,x.mp4,0,1\n")
    for clip, csv_file, message in (
            (short, labels, f"{short}: 20 frames decoded, but {labels} labels frame 21 (1-based) and 72 more"),
            (video, extra, f"{video}: 93 frames decoded, but {extra} labels frame 5000 (1-based) and 0 more")):
        r = run_merlion("eval", "auroc", str(clip), "--labels", str(csv_file), "--encoder", "visual")
        assert r.returncode != 0
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"merlion: error: {message}"), r.stderr
