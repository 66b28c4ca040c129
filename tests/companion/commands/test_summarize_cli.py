"""`merlion summarize` end to end on the survey video: summary.json schema, frames, contact sheet, refusals."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from companion.config import load_config
from companion.errors import MerlionError
from companion.vision.contact_sheet import Tile, contact_sheet, format_time
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.summarize import summarize
from tests.conftest import run_merlion, shared_file

SURVEY = "survey/survey_480x270.mp4"


def one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.startswith("merlion: error:")]
    assert len(lines) == 1, stderr
    return lines[0]


@pytest.fixture(scope="module")
def summary_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "dive"
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--encoder", "imagenet",
                       "--fps", "1", "-k", "3", "--threshold", "45")
    assert proc.returncode == 0, proc.stderr
    assert "%|" not in proc.stderr  # no progress bar when stderr is not a terminal
    assert str(out) in proc.stdout
    return out


def test_summary_json_schema_and_frames(summary_dir):
    doc = json.loads((summary_dir / "summary.json").read_text())
    assert set(doc) == {"source", "encoder", "params", "frames"}
    assert doc["source"].endswith("survey_480x270.mp4")
    assert doc["encoder"].startswith("imagenet")
    params = doc["params"]
    assert params["k"] == 3 and params["tau_ss"] == pytest.approx(0.45) and params["fps"] == 1
    assert params["query"] == "underwater image with fish"
    assert params["negatives"] == ["underwater image without fish"]
    assert [(t["name"], t["query"], t["frames"], t["contact_sheet"]) for t in params["topics"]] == [
        ("main", "underwater image with fish", len(doc["frames"]), "contact_sheet.jpg")]
    frames = doc["frames"]
    assert 1 <= len(frames) <= 3
    assert [f["time_s"] for f in frames] == sorted(f["time_s"] for f in frames)
    labels = {}
    for line in shared_file("survey/survey_480x270_labels.csv").read_text().splitlines()[1:]:
        cells = line.split(",")
        labels[int(cells[0])] = cells[-1].strip() == "1"
    for f in frames:
        assert set(f) == {"index", "time_s", "score", "raw_score", "file", "topic", "below_threshold"}
        assert f["topic"] == "main" and f["below_threshold"] is False  # the one default topic; frames passed
        assert f["raw_score"] is None  # no enhancement: the score is the frame's own
        assert f["index"] % 10 == 0  # 10 fps source at --fps 1
        assert f["time_s"] == pytest.approx(f["index"] / 10.0)
        assert 0.45 < f["score"] <= 1.0
        assert f["file"].startswith("frames/") and f["file"].endswith(".jpg")
        image = cv2.imread(str(summary_dir / f["file"]))
        assert image is not None and image.shape == (270, 480, 3)  # full resolution
    assert sum(labels[f["index"]] for f in frames) >= len(frames) - 1  # fish frames, at most one stray
    assert sorted(p.name for p in (summary_dir / "frames").iterdir()) == sorted(
        f["file"].split("/")[1] for f in frames)
    sheet = cv2.imread(str(summary_dir / "contact_sheet.jpg"))
    assert sheet is not None and sheet.shape[1] >= 320


def test_existing_dir_is_refused_without_force_and_left_alone(summary_dir):
    before = (summary_dir / "summary.json").read_bytes()
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(summary_dir), "--encoder", "visual")
    assert proc.returncode != 0
    assert "--force" in one_error_line(proc.stderr)
    assert (summary_dir / "summary.json").read_bytes() == before


def test_force_replaces_the_directory(tmp_path):
    out = tmp_path / "again"
    out.mkdir()
    (out / "stale.txt").write_text("old")
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--encoder", "visual",
                       "--fps", "1", "-k", "3", "--force")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "summary.json").read_text())
    assert doc["encoder"] == "visual" and len(doc["frames"]) == 3
    assert not (out / "stale.txt").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_bad_input_is_one_line_and_nonzero(tmp_path):
    out = tmp_path / "out"
    missing = tmp_path / "missing.mp4"
    proc = run_merlion("summarize", str(missing), "--out", str(out), "--encoder", "visual")
    assert proc.returncode == 2  # bad input: exit 2, as every other bad input
    assert one_error_line(proc.stderr) == f"merlion: error: source {missing}: no such file or folder"
    assert not out.exists()
    broken = tmp_path / "broken.mp4"
    data = shared_file(SURVEY).read_bytes()
    broken.write_bytes(data[: len(data) // 3])
    proc = run_merlion("summarize", str(broken), "--out", str(out), "--encoder", "visual")
    assert proc.returncode != 0
    assert "broken.mp4" in one_error_line(proc.stderr)
    assert not out.exists()
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--threshold", "-0.2")  # 0 is valid (no gate); below 0 is not
    assert proc.returncode == 2
    assert "tau_ss" in one_error_line(proc.stderr)


def test_a_bad_option_is_blamed_on_the_option_and_its_value_shown_once(tmp_path):
    out = tmp_path / "out"
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "-k", "-3")
    assert proc.returncode == 2
    assert one_error_line(proc.stderr) == ("merlion: error: -k: sampler.k: Input should be greater than or equal "
                                           "to 1 (got -3)")
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--threshold", "-1")
    line = one_error_line(proc.stderr)
    assert proc.returncode == 2 and line.startswith("merlion: error: --threshold: queries.tau_ss: ")
    assert line.count("-1.0") == 1, line
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--threshold", "150")
    line = one_error_line(proc.stderr)  # read as a percentage, 1.5: the message shows what was given
    assert proc.returncode == 2 and line.endswith("a percentage in (1, 100), got 150.0"), line
    assert not out.exists()


def test_an_output_folder_that_cannot_be_written_fails_before_the_work():
    """Its parent exists but nothing can be made in it (/proc/self refuses new entries, even to root)."""
    cfg = load_config(None, overrides={"source": {"uri": "synthetic://dive?seconds=1&width=64&height=64"}})
    with pytest.raises(MerlionError, match=r"^/proc/self/summary: cannot write there \("):
        summarize(cfg, "/proc/self/summary", encoder=VisualEncoder())


def test_progress_bar_only_when_asked_or_on_a_terminal(tmp_path, capsys):
    cfg = load_config(None, overrides={"source": {"uri": str(shared_file(SURVEY)), "fps": 1}, "sampler": {"k": 2}})
    encoder = VisualEncoder()
    summarize(cfg, tmp_path / "quiet", encoder=encoder)  # stderr is not a terminal under pytest
    assert "%|" not in capsys.readouterr().err
    run = summarize(cfg, tmp_path / "loud", encoder=encoder, progress=True)
    assert "%|" in capsys.readouterr().err
    assert run.frames_seen == 10 and run.frames_lost == 0
    with pytest.raises(MerlionError, match="already exists"):
        summarize(cfg, tmp_path / "loud", encoder=encoder)


def test_contact_sheet_grid_and_labels():
    tiles = [Tile(np.full((270, 480, 3), 200, np.uint8), t, 0.5) for t in (0.0, 1.5, 62.0, 3725.0, 9.0)]
    sheet = contact_sheet(tiles, tile_width=160)
    assert sheet.shape[1] == 3 * 160 + 4 * 4  # 5 tiles: 3 columns, 2 rows
    assert sheet.shape[0] > 2 * 90
    assert format_time(62.0) == "1:02.0" and format_time(3725.0) == "1:02:05.0"
    band = sheet[4 + 90:4 + 90 + 24, 4:164]
    assert (band > 200).any()  # label text drawn under the first tile
    empty = contact_sheet([])
    assert empty.ndim == 3 and empty.size > 0


def test_truncated_video_is_summarized_and_the_loss_reported(tmp_path):
    from tests.companion.sources.test_sources import faststart

    whole = faststart(shared_file(SURVEY).read_bytes())
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(whole[: int(len(whole) * 0.6)])
    proc = run_merlion("summarize", str(cut), "--out", str(tmp_path / "out"), "--encoder", "visual", "--fps", "2")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    stats = doc["params"]["stats"]
    assert stats["frames_lost"] > 0 and stats["frames_seen"] > 0
    # each count in its unit: frames kept at --fps, lost ones at the video's own rate (and as seconds)
    assert f"from {stats['frames_seen']} frames read at 2 fps (" in proc.stdout, proc.stdout
    assert (f"; {stats['frames_lost']} frames of the video at its own 10 fps ({stats['frames_lost'] / 10:.1f} s) "
            f"could not be decoded;") in proc.stdout, proc.stdout
    assert not re.search(r"\b1 frames", proc.stdout + proc.stderr)


def test_a_clip_no_frame_passes_keeps_its_best_frames_marked_below_threshold(tmp_path):
    """A real ROV clip with no fish, asked for "fish": not an empty summary, but the best-scoring frames, each
    marked below the threshold in summary.json and the closing line (issue 23 item 3)."""
    out = tmp_path / "rov"
    clip = shared_file("rov_clips/V4361_20211006T163256Z_h265_1sec.mp4")
    proc = run_merlion("summarize", str(clip), "--out", str(out), "--encoder", "imagenet", "--query", "fish",
                       "--fps", "10", "--explain")
    assert proc.returncode == 0, proc.stderr
    assert "positive query 'fish':\n  fish -> fish [noun]: 16 classes: tench," in proc.stderr
    doc = json.loads((out / "summary.json").read_text())
    frames = doc["frames"]
    assert doc["params"]["stats"]["frames_passed"] == 0
    assert 1 <= len(frames) <= 3 and all(f["below_threshold"] is True for f in frames)
    assert all(0 <= f["score"] <= doc["params"]["tau_ss"] for f in frames)
    assert doc["params"]["topics"][0]["below_threshold"] is True and doc["params"]["topics"][0]["frames"] == len(frames)
    assert all((out / f["file"]).is_file() for f in frames)
    n = len(frames)
    said = (f"{n} summary frame{'s' * (n > 1)} from {doc['params']['stats']['frames_seen']} frames read at 10 fps (nothing passed the query; the "
            f"{n} best frame{'s are' if n > 1 else ' is'} kept, marked below the threshold)")
    assert said in proc.stdout, proc.stdout
    assert "no more distinct views that passed" not in proc.stdout  # nothing passed: no contradiction after it
    assert doc["params"]["short"] == [f"main: {said.split('(')[1].rstrip(')')}"]


def test_an_mp4_cut_before_its_index_says_why_and_how_to_recover(tmp_path):
    """The survey's index (moov) is at its end, as most recorders write it: a copy cut short cannot be opened at
    all, and the one line says that a recording cut short leaves an MP4 without its index, and what to do."""
    data = shared_file(SURVEY).read_bytes()
    assert data.find(b"moov") > len(data) // 2  # the index is written last in this file
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:200_000])
    proc = run_merlion("summarize", str(cut), "--out", str(tmp_path / "out"), "--encoder", "visual")
    assert proc.returncode == 2  # nothing can be read: bad input (README: exit 2), as in run and demo
    line = one_error_line(proc.stderr)
    assert line.startswith(f"merlion: error: {cut}: cannot be opened as a video: an MP4 without its index")
    assert "recording cut short" in line and "untrunc" in line and ".mkv" in line
    other = tmp_path / "notes.mp4"
    other.write_text("not a video")
    proc = run_merlion("summarize", str(other), "--out", str(tmp_path / "out"), "--encoder", "visual")
    assert proc.returncode == 2
    assert "(unknown format, or damaged beyond reading)" in one_error_line(proc.stderr)
