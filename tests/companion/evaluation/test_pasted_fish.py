"""Pasted-fish training frames for the scene head (companion.evaluation.pasted_fish), and the rule that keeps them
out of every figure: training-only rows, held out with each group they name."""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.errors import MerlionError
from companion.evaluation.dive_centring import stream_order
from companion.evaluation.head_training import _ridge_all, fit, held_out_scores, nested_holdout
from companion.evaluation.pasted_fish import MIN_BOX, PastedFish, fish_crops, paste, pasted_images
from companion.evaluation.scene_holdout import pasted_scene_features
from companion.evaluation.sources import DEEPFISH, LabelledFrame, load_sources
from companion.vision.encoders.learned_head import load_head
from companion.vision.scene_memory import SceneInput, SceneMemory
from tests.conftest import SHARED_DATA, run_merlion, shared_file


@pytest.fixture(scope="module")
def crops() -> list[np.ndarray]:
    shared_file("aquarium_fish/frames/000001.xml")
    return fish_crops(SHARED_DATA)


def test_crops_are_the_aquarium_frames_labelled_fish(crops):
    assert len(crops) > 200  # 50 frames, 3-8 boxes each, the smallest left out
    assert all(c.ndim == 3 and c.shape[1] > MIN_BOX[0] and c.shape[0] > MIN_BOX[1] for c in crops)


def test_paste_adds_small_fish_and_leaves_the_rest_of_the_frame(crops):
    frame = np.full((202, 360, 3), (120, 140, 60), np.uint8)  # a turbid green sea floor, DeepFish's size
    out = paste(frame, crops, np.random.default_rng(0))
    again = paste(frame, crops, np.random.default_rng(0))
    changed = np.abs(out.astype(int) - frame).max(axis=2) > 3
    assert out.shape == frame.shape and out.dtype == np.uint8 and np.array_equal(out, again)
    assert 0 < changed.mean() < 0.1  # 1-3 fish of 8-48 px in a 360 x 202 frame
    assert not np.array_equal(paste(frame, crops, np.random.default_rng(1)), out)


def test_only_empty_deepfish_frames_get_pasted_copies(crops):
    shared_file("deepfish/labels.csv")
    frames = load_sources(SHARED_DATA)
    base, images = pasted_images(frames, crops)
    empty = [i for i, f in enumerate(frames) if f.source.startswith(DEEPFISH) and not f.fish]
    assert len(empty) == 300 and sorted(set(base.tolist())) == empty and len(images) == 600
    assert all(images[k].shape == frames[i].image.shape for k, i in enumerate(base[:20]))
    assert np.array_equal(pasted_images(frames, crops)[1][5], images[5])  # reproducible: the shipped head depends on it


def test_a_folder_without_boxes_is_refused_naming_it(tmp_path):
    (tmp_path / "aquarium_fish" / "frames").mkdir(parents=True)
    with pytest.raises(MerlionError, match="aquarium_fish/frames: no fish boxes"):
        fish_crops(tmp_path)


def _voc(folder: Path, name: str, boxes: str) -> None:
    cv2.imwrite(str(folder / f"{name}.jpg"), np.full((100, 200, 3), 90, np.uint8))
    (folder / f"{name}.xml").write_text(f"<annotation><object><name>Fish</name>{boxes}</object></annotation>")


def test_boxes_outside_the_frame_are_cut_as_far_as_the_frame_goes_and_bad_files_are_named(tmp_path):
    folder = tmp_path / "aquarium_fish" / "frames"
    folder.mkdir(parents=True)
    box = "<bndbox><xmin>{}</xmin><ymin>{}</ymin><xmax>{}</xmax><ymax>{}</ymax></bndbox>"
    _voc(folder, "a", box.format(150, 10, 260, 60) + box.format(250, 10, 400, 60) + box.format(-50, -50, 20, 20))
    [crop] = fish_crops(tmp_path)  # the first cut to the frame's edge (50 x 50); the others leave nothing to cut
    assert crop.shape == (50, 50, 3)
    (folder / "b.jpg").write_bytes((folder / "a.jpg").read_bytes())
    (folder / "b.xml").write_text("<annotation><object>")
    with pytest.raises(MerlionError, match=r"b\.xml: not a Pascal-VOC box file"):
        fish_crops(tmp_path)
    (folder / "b.xml").write_text("<annotation><object><bndbox><xmin>3</xmin></bndbox></object></annotation>")
    with pytest.raises(MerlionError, match=r"b\.xml: a box lacks one of xmin"):
        fish_crops(tmp_path)


def test_pasted_copies_are_judged_as_if_they_came_in_place_of_their_original():
    rng = np.random.default_rng(3)
    pixels = np.clip(0.4 + rng.normal(0, 0.05, size=(8, 64, 112, 3)), 0, 1)
    views = SceneInput(rng.normal(size=(8, 3, 4)), pixels)
    # one DeepFish habitat: streamed in a seeded shuffled order, not in file order
    frames = [LabelledFrame(f"{DEEPFISH}1", f"f{i}", False, np.zeros((2, 2, 3), np.uint8)) for i in range(8)]
    base = np.arange(8)
    copies = SceneInput(views.views + rng.normal(0, 2, size=views.views.shape), np.clip(pixels + 0.1, 0, 1))
    pasted = PastedFish(base=base, groups=np.array([f"{DEEPFISH}1+aquarium"] * 8), scene=copies)
    got = pasted_scene_features(views, frames, pasted, seed=1)
    assert got.shape == (8, 4 + 12)
    [order] = stream_order(frames, 1)
    assert order.tolist() != list(range(8))
    assert np.isnan(got[order[0]]).all() and np.isfinite(np.delete(got, order[0], axis=0)).all()
    for t in range(1, 8):
        memory = SceneMemory()
        memory.residuals(views[order[:t]])  # the dive as it stood before frame order[t]
        want = memory.residuals(copies[order[t]])[0]  # the copy joins as a real frame would
        np.testing.assert_allclose(got[order[t]], want, rtol=1e-12, atol=1e-12)
    # what comes after a frame never reaches its copy
    later = SceneInput(views.views.copy(), pixels.copy())
    later.views[order[5:]] += 100.0
    later.pixels[order[5:]] = 1.0 - later.pixels[order[5:]]
    np.testing.assert_allclose(pasted_scene_features(later, frames, pasted, seed=1)[order[:6]], got[order[:6]])


def test_with_each_clip_a_dive_a_copy_is_judged_against_its_own_clip_only():
    rng = np.random.default_rng(4)
    pixels = np.clip(0.4 + rng.normal(0, 0.05, size=(10, 64, 112, 3)), 0, 1)
    views = SceneInput(rng.normal(size=(10, 3, 4)), pixels)
    clips = ["F1"] * 4 + ["NF2"] * 6
    frames = [LabelledFrame(f"{DEEPFISH}1", f"f{i}", i < 4, np.zeros((2, 2, 3), np.uint8), clips[i])
              for i in range(10)]
    base = np.arange(4, 10)  # copies of the empty frames (clip NF2)
    copies = SceneInput(views.views[base] + 1.0, np.clip(pixels[base] + 0.1, 0, 1))
    pasted = PastedFish(base=base, groups=np.array([f"{DEEPFISH}1+aquarium"] * 6), scene=copies)
    got = pasted_scene_features(views, frames, pasted, seed=2, by_clip=True)
    [fish, empty] = stream_order(frames, 2, by_clip=True)
    assert sorted(fish.tolist()) == [0, 1, 2, 3] and sorted(empty.tolist()) == list(range(4, 10))
    for t in range(1, 6):  # against the empty clip's frames before the original, never the fish clip's
        memory = SceneMemory()
        memory.residuals(views[empty[:t]])
        k = int(np.flatnonzero(base == empty[t])[0])
        np.testing.assert_allclose(got[k], memory.residuals(copies[k])[0], rtol=1e-12, atol=1e-12)
    assert np.isnan(got[int(np.flatnonzero(base == empty[0])[0])]).all()  # its clip's first frame: no scene
    assert not np.allclose(np.nan_to_num(got), np.nan_to_num(pasted_scene_features(views, frames, pasted, seed=2)))


def _groups_data(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(120, 10))
    y = np.arange(120) % 2 == 0
    x[y, 0] += 2.0
    return x, y, np.repeat([f"g{k}" for k in range(4)], 30)


def test_extra_rows_train_every_fold_but_the_groups_they_name():
    x, y, g = _groups_data()
    rng = np.random.default_rng(1)
    ex = rng.normal(size=(40, 10))
    eg = np.array(["g0+aquarium"] * 20 + ["g1+aquarium"] * 20)
    plain = held_out_scores(x, y, g, [10.0])[10.0]
    a = held_out_scores(x, y, g, [10.0], extra=(ex, np.ones(40, bool), eg))[10.0]
    moved = ex.copy()
    moved[:20] += 50.0  # g0's extra rows changed: g0's own scores must not move, the others' must
    b = held_out_scores(x, y, g, [10.0], extra=(moved, np.ones(40, bool), eg))[10.0]
    assert np.allclose(a[g == "g0"], b[g == "g0"]) and not np.allclose(a[g == "g1"], b[g == "g1"])
    assert not np.allclose(a[g == "g2"], plain[g == "g2"])  # they are trained on where no named group is held out
    # the crops' own group held out: no extra row at all (every one names it)
    g2 = np.where(g == "g3", "aquarium", g)
    c = held_out_scores(x, y, g2, [10.0], extra=(ex, np.ones(40, bool), eg))[10.0]
    assert np.allclose(c[g2 == "aquarium"], held_out_scores(x, y, g2, [10.0])[10.0][g2 == "aquarium"])
    probs, chosen = nested_holdout(x, y, g, (1.0, 100.0), extra=(ex, np.ones(40, bool), eg))
    again, chosen_again = nested_holdout(x, y, g, (1.0, 100.0), extra=(moved, np.ones(40, bool), eg))
    assert set(chosen) == {"g0", "g1", "g2", "g3"} and len(probs) == 120
    # nested too: g0's pasted rows reach neither g0's head nor the strength chosen for it
    assert np.allclose(probs[g == "g0"], again[g == "g0"]) and chosen["g0"] == chosen_again["g0"]
    assert not np.allclose(probs[g == "g1"], again[g == "g1"])


def test_platt_calibrates_on_the_real_rows_only():
    x, y, _ = _groups_data()
    extra = x[y] + 0.1  # many more fish: calibrated on them, every probability would rise
    both = np.concatenate([x, extra]), np.concatenate([y, np.ones(len(extra), bool)])
    real_only = fit(*both, 10.0, calibrate=len(y))
    with_extra_too = fit(*both, 10.0)
    p_real = 1 / (1 + np.exp(-(x @ real_only.w + real_only.b)))
    p_all = 1 / (1 + np.exp(-(x @ with_extra_too.w + with_extra_too.b)))
    assert abs(p_real.mean() - y.mean()) < 0.05 < p_all.mean() - y.mean()
    assert np.allclose(real_only.w / np.linalg.norm(real_only.w), with_extra_too.w / np.linalg.norm(with_extra_too.w))


@pytest.mark.parametrize("rows", [60, 300])  # fewer frames than features, and more
def test_ridge_solves_equal_the_svd_solution(rows):
    rng = np.random.default_rng(rows)
    x, y = rng.normal(size=(rows, 120)), rng.random(rows) < 0.5
    mean, scale, fits = _ridge_all(x, y, [1.0, 100.0])
    z = (x - mean) / scale
    t = np.where(y, 1.0, -1.0)
    u, sv, vt = np.linalg.svd(z, full_matrices=False)
    for lam, (w, offset) in zip([1.0, 100.0], fits, strict=True):
        np.testing.assert_allclose(w, vt.T @ (sv / (sv * sv + lam) * (u.T @ (t - t.mean()))), rtol=1e-8, atol=1e-10)
        assert offset == pytest.approx(t.mean())


def _clip(src: Path, dst: Path, frames: Sequence[int]) -> None:
    """The given frames of a real video, written as a short clip (keeps the end-to-end test quick)."""
    video = cv2.VideoCapture(str(src))
    images = []
    ok, image = video.read()
    while ok and len(images) <= max(frames):
        images.append(image)
        ok, image = video.read()
    video.release()
    height, width = images[0].shape[:2]
    out = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"mp4v"), 10, (width, height))
    for i in frames:
        out.write(images[i])
    out.release()


def _small_data(root: Path, *, boxes: bool = True) -> Path:
    """The shared data folder's layout, small: one DeepFish habitat, six aquarium frames, 2 frames of the aquarium
    video and 12 of the survey (the real files, linked or cut), so that both heads train from the command fast."""
    src = SHARED_DATA
    data = root / "data"
    (data / "deepfish" / "images").mkdir(parents=True)
    with (src / "deepfish" / "labels.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    keep = [r for r in rows if r["habitat_id"] == "9907"]
    with (data / "deepfish" / "labels.csv").open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(keep)
    for r in keep:
        (data / "deepfish" / r["file"]).symlink_to(src / "deepfish" / r["file"])
    (data / "suim").symlink_to(src / "suim")
    (data / "survey").mkdir()
    survey = list(range(0, 93, 8))  # both fish and no-fish segments
    _clip(src / "survey" / "survey_480x270.mp4", data / "survey" / "survey_480x270.mp4", survey)
    with (src / "survey" / "survey_480x270_labels.csv").open(newline="", encoding="utf-8") as fh:
        labels = list(csv.DictReader(fh))
    with (data / "survey" / "survey_480x270_labels.csv").open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(labels[0]))
        writer.writeheader()
        writer.writerows([{**labels[i], "frame_index": str(k)} for k, i in enumerate(survey)])
    (data / "aquarium_fish" / "frames").mkdir(parents=True)
    _clip(src / "aquarium_fish" / "fish.mp4", data / "aquarium_fish" / "fish.mp4", range(0, 400, 10))
    for n in range(1, 7):
        for ext in (".jpg", ".xml") if boxes else (".jpg",):
            name = f"{n:06d}{ext}"
            (data / "aquarium_fish" / "frames" / name).symlink_to(src / "aquarium_fish" / "frames" / name)
    return data


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_train_head_and_eval_auroc_learn_from_pasted_fish_end_to_end(tmp_path):
    shared_file("aquarium_fish/frames/000006.xml")
    shared_file("deepfish/labels.csv")
    data = _small_data(tmp_path)
    scene = tmp_path / "fish-scene.json"
    done = run_merlion("eval", "train-head", "--data", str(data), "--out", str(tmp_path / "fish.json"),
                       "--scene-out", str(scene), "--json", timeout=500)
    assert done.returncode == 0, done.stderr
    assert "fish pasted in" in done.stderr  # the slow step says what it is doing
    figures = json.loads(done.stdout)
    head = load_head(scene)
    # 30 empty frames x 2 copies, less the copies of a dive's first frame (no scene to judge them against)
    assert head.input == "scene" and 58 <= head.trained_on["extra_rows"]["rows"] <= 60
    assert head.trained_on["extra_rows"]["positives"] == head.trained_on["extra_rows"]["rows"]
    assert set(figures["scene"]["groups"]) >= {"deepfish:9907", "suim", "aquarium"}
    done = run_merlion("eval", "auroc", "--data", str(data), "--holdout", "--orders", "4", "--json", timeout=500)
    assert done.returncode == 0, done.stderr
    # long work shows progress on stderr, the JSON alone on stdout
    frames = json.loads(done.stdout)["frames"]
    assert f"encoding: {frames} of {frames} frames" in done.stderr
    assert "scene head, order seed 3 (4 of 4)" in done.stderr
    assert "scene head, each clip a dive, order seed 0 (1 of 4)" in done.stderr
    result = json.loads(done.stdout)["scene"]
    assert "60 pasted-fish copies of 30 empty frames" in result["method"]
    assert set(result["orders"]) == {"0", "1", "2", "3"}
    assert all(o["deepfish_habitats"]["groups"] == 1 for o in result["orders"].values())
    habitat = [o["deepfish_habitats"]["mean"] for o in result["orders"].values()]
    assert result["over_orders"]["deepfish_habitats_mean"] == pytest.approx(
        {"orders": 4, "mean": np.mean(habitat), "min": min(habitat), "max": max(habitat)})
    assert result["over_orders"]["pooled"]["mean"] == pytest.approx(
        np.mean([o["pooled"] for o in result["orders"].values()]))
    by_clip = json.loads(done.stdout)["scene_by_clip"]  # the same with each DeepFish clip its own dive
    assert "each DeepFish clip its own dive" in by_clip["method"] and set(by_clip["orders"]) == {"0", "1", "2", "3"}
    assert all(o["deepfish_habitats"]["groups"] == 1 for o in by_clip["orders"].values())
    assert by_clip["orders"]["0"]["by_group"] != result["orders"]["0"]["by_group"]


def test_train_head_without_the_fish_boxes_is_one_line_naming_the_folder(tmp_path):
    shared_file("aquarium_fish/frames/000006.jpg")
    shared_file("deepfish/labels.csv")
    data = _small_data(tmp_path, boxes=False)
    done = run_merlion("eval", "train-head", "--data", str(data), "--scene-out", str(tmp_path / "s.json"),
                       timeout=500)
    assert done.returncode != 0 and not (tmp_path / "s.json").exists()
    last = done.stderr.strip().splitlines()[-1]
    assert "aquarium_fish/frames: no fish boxes to paste" in last and "Traceback" not in done.stderr
