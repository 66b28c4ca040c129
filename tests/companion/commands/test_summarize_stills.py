"""`merlion summarize` on a folder of stills (real DeepFish photos): every summary frame names its own file, in
summary.json, the exports and the contact sheet; the frame gate, made for a video's near-identical neighbours,
stays off unless the configuration asks for it, and the closing line says what it skipped."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from companion.vision.contact_sheet import Tile, contact_sheet, fit_text
from tests.conftest import run_merlion, shared_file

STILLS = 80


@pytest.fixture(scope="module")
def stills(tmp_path_factory):
    source = shared_file("deepfish/images")
    folder = tmp_path_factory.mktemp("stills") / "photos"
    folder.mkdir()
    for path in sorted(source.iterdir())[:STILLS]:
        shutil.copy(path, folder / path.name)
    return folder


def test_each_summary_frame_names_its_still_and_no_still_is_skipped(stills, tmp_path):
    out = tmp_path / "sum"
    proc = run_merlion("summarize", str(stills), "--out", str(out), "--encoder", "visual")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "summary.json").read_text())
    stats = doc["params"]["stats"]
    assert stats["frames_skipped"] == 0 and stats["frames_encoded"] == STILLS
    assert doc["params"]["gate"]["mode"] == "none"
    assert f"6 summary frames from {STILLS} images (" in proc.stdout and "skipped" not in proc.stdout
    names = sorted(p.name for p in stills.iterdir())
    for f in doc["frames"]:
        assert f["source"] == names[f["index"]]
        kept = cv2.imread(str(out / f["file"])).astype(np.int16)
        original = cv2.imread(str(stills / f["source"])).astype(np.int16)
        assert kept.shape == original.shape and np.abs(kept - original).mean() < 3  # the same photo, re-encoded
    csv_out = tmp_path / "frames.csv"
    proc = run_merlion("export", str(out), "--format", "csv", "--out", str(csv_out))
    assert proc.returncode == 0, proc.stderr
    text = csv_out.read_text()
    assert all(f"(atr) source {f['source']}" in text for f in doc["frames"])
    coco_out = tmp_path / "coco.json"
    assert run_merlion("export", str(out), "--format", "coco", "--out", str(coco_out)).returncode == 0
    images = json.loads(coco_out.read_text())["images"]
    assert [i["source"] for i in images] == [f["source"] for f in doc["frames"]]


def test_a_gate_the_configuration_asks_for_applies_and_the_closing_line_counts_its_skips(stills, tmp_path):
    config = tmp_path / "gated.yaml"
    config.write_text("gate:\n  mode: difference\n")
    out = tmp_path / "gated"
    proc = run_merlion("summarize", str(stills), "--out", str(out), "--encoder", "visual", "--config", str(config))
    assert proc.returncode == 0, proc.stderr
    stats = json.loads((out / "summary.json").read_text())["params"]["stats"]
    assert 0 < stats["frames_skipped"] < STILLS
    assert f"; {stats['frames_skipped']} skipped by the frame gate)" in proc.stdout


def test_a_still_is_labelled_by_its_file_name_shortened_to_fit():
    name = "7117_Caranx_sexfasciatus_juvenile_f000093.jpg"
    font = cv2.FONT_HERSHEY_SIMPLEX
    label = fit_text(name, "   score 0.98", 312, font, 0.5, 1)
    assert label.startswith("7117_") and label.endswith("f000093.jpg   score 0.98") and "..." in label
    assert cv2.getTextSize(label, font, 0.5, 1)[0][0] <= 312
    assert fit_text("a.jpg", "   score 0.98", 312, font, 0.5, 1) == "a.jpg   score 0.98"
    image = np.full((90, 160, 3), 120, np.uint8)
    by_time = contact_sheet([Tile(image, 0.8, 0.5)], tile_width=160)
    by_name = contact_sheet([Tile(image, 0.8, 0.5, label="still.jpg")], tile_width=160)
    assert by_time.shape == by_name.shape and not np.array_equal(by_time, by_name)  # the band says the name
