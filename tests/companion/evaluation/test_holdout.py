"""Per-source and leave-one-group-out AUROC (companion.evaluation.holdout) and the source split of the shared data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.evaluation.holdout import leave_one_group_out, over_orders, per_source
from companion.evaluation.sources import GROUPS, LabelledFrame, load_sources, murky
from tests.conftest import SHARED_DATA, run_merlion, shared_file

PIXEL = np.zeros((2, 2, 3), np.uint8)


def _frames(spec: list[tuple[str, bool]]) -> list[LabelledFrame]:
    return [LabelledFrame(src, f"{i}", fish, PIXEL) for i, (src, fish) in enumerate(spec)]


def test_one_class_sources_are_ranked_against_the_other_class_of_the_rest():
    frames = _frames([("suim", True), ("suim", False), ("aquarium_frames", True), ("aquarium_frames", True),
                      ("rov_clips", False)])
    scores = [0.9, 0.1, 0.8, 0.05, 0.3]
    out = per_source(scores, frames)
    assert out["suim"] == 1.0
    # aquarium fish 0.8, 0.05 against the no-fish frames of the rest 0.1, 0.3: 2 of 4 pairs won
    assert out["aquarium_frames"] == 0.5
    # rov no-fish 0.3 against the fish of the rest 0.9, 0.8 (the aquarium 0.05 counts too): 2 of 3
    assert out["rov_clips"] == pytest.approx(2 / 3)
    assert out["pooled"] == pytest.approx(4 / 6)


def test_held_out_choice_uses_only_the_other_groups():
    frames = _frames([("suim", True), ("suim", False), ("aquarium_frames", True), ("rov_clips", False),
                      ("survey", True), ("survey", False)])
    # "a" is perfect outside suim but inverted on it; "b" is perfect on suim only
    variants = {"a": [0.1, 0.9, 0.9, 0.1, 0.9, 0.1], "b": [0.9, 0.1, 0.1, 0.9, 0.1, 0.9]}
    rows = {r["held_out"]: r for r in leave_one_group_out(variants, frames)}
    assert set(rows) == {"suim", "aquarium", "rov"}
    assert rows["suim"]["chosen"] == "a" and rows["suim"]["held_out_auroc"] == 0.0
    assert rows["suim"]["all"]["b"] == 1.0
    # holding out aquarium also holds out the survey, which is cut from it
    assert rows["aquarium"]["chosen"] == "b"


def test_murky_copy_is_green_cast_softer_and_same_size():
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    out = murky(image)
    assert out.shape == image.shape and out.dtype == np.uint8
    b, g, r = out.reshape(-1, 3).mean(axis=0)
    assert g > r + 40 and g > b
    assert out.std() < image.std() / 2


def test_shared_data_split_by_source():
    shared_file("suim/labels.csv")
    frames = load_sources(SHARED_DATA, survey=False, deepfish=False)
    by = {}
    for f in frames:
        by.setdefault(f.source, []).append(f.fish)
    assert sorted(by) == ["aquarium_frames", "aquarium_video", "rov_clips", "suim"]
    assert sum(by["suim"]) == 4 and len(by["suim"]) == 8
    assert all(by["aquarium_frames"]) and all(by["aquarium_video"]) and not any(by["rov_clips"])
    assert {f.group for f in frames} <= set(GROUPS.values())


@pytest.mark.slow
def test_eval_auroc_by_source_with_the_visual_baseline_is_chance(tmp_path):
    shared_file("suim/labels.csv")
    r = run_merlion("eval", "auroc", "--data", str(SHARED_DATA), "--encoder", "visual", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    habitats = {k for k in out["auroc"] if k.startswith("deepfish:")}
    assert set(out["auroc"]) - habitats == {"suim", "aquarium_frames", "aquarium_video", "rov_clips", "survey",
                                            "pooled"}
    assert len(habitats) == (10 if (SHARED_DATA / "deepfish" / "labels.csv").is_file() else 0)
    assert all(v == 0.5 for v in out["auroc"].values())
    assert set(out["by_group"]) == habitats | {"suim", "aquarium", "rov", "pooled"}
    if habitats:
        assert out["deepfish_habitats"] == {"groups": 10, "mean": 0.5, "min": 0.5, "max": 0.5, "spread": 0.0}
    bad = run_merlion("eval", "auroc", "--data", str(tmp_path), "--encoder", "visual")
    assert bad.returncode == 2
    assert bad.stderr.strip() == f"merlion: error: {tmp_path}: not the shared data folder (no suim/labels.csv)"


@pytest.mark.parametrize(("labels", "message"), [
    (None, "survey_480x270_labels.csv: missing from the shared data folder"),
    ("frame_index,fish_present\n0,0\n1,1\n", "survey_480x270_labels.csv: 2 rows, but survey_480x270.mp4 has more frames"),
    ("frame_index,fish\n0,0\n", "survey_480x270_labels.csv: needs a header with fish_present and one row per frame"),
])
@pytest.mark.slow
def test_a_broken_data_folder_is_one_line_naming_the_file(tmp_path, labels, message):
    """A data folder with the survey's label file missing, short or without its column (was a traceback)."""
    shared_file("survey/survey_480x270.mp4")
    for part in ("suim", "aquarium_fish", "rov_clips"):
        (tmp_path / part).symlink_to(SHARED_DATA / part)
    (tmp_path / "survey").mkdir()
    (tmp_path / "survey" / "survey_480x270.mp4").symlink_to(SHARED_DATA / "survey" / "survey_480x270.mp4")
    if labels is not None:
        (tmp_path / "survey" / "survey_480x270_labels.csv").write_text(labels)
    done = run_merlion("eval", "auroc", "--data", str(tmp_path), "--encoder", "visual", timeout=240)
    assert done.returncode != 0
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], done.stderr


def test_over_orders_summarises_each_figure_over_the_frame_orders():
    orders = {"0": {"pooled": 0.8, "habitats": {"mean": 0.86}}, "1": {"pooled": 0.9, "habitats": {"mean": 0.84}},
              "2": {"pooled": 0.7, "habitats": {"mean": 0.85}}}
    out = over_orders(orders, {"pooled": "pooled", "habitat_mean": "habitats.mean"})
    assert out["pooled"] == pytest.approx({"orders": 3, "mean": 0.8, "min": 0.7, "max": 0.9})
    assert out["habitat_mean"] == pytest.approx({"orders": 3, "mean": 0.85, "min": 0.84, "max": 0.86})
    assert over_orders({}, {"pooled": "pooled"}) == {}
