"""``merlion export``: a real store and a real summarize folder written as FathomNet image records (read back with
fathomnet-py's own ``Image``), COCO (loaded with pycocotools' ``COCO()``) and VIAME/DIVE CSV (parsed by DIVE's
documented rules); the campaign report links the three; bad input is one line and exit 2."""

from __future__ import annotations

import csv
import hashlib
import json
import math
import re
import shutil
from pathlib import Path
from urllib.parse import urlparse

import cv2
import numpy as np
import pytest

from companion.archive.report import write_campaign_report
from companion.commands.export import FORMAT_NAMES
from companion.config import StoreConfig
from companion.export.viame_csv import HEADER
from companion.export.writer import FORMATS
from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.conftest import run_merlion, shared_file
from vehicle.autopilot.pose import Pose

SURVEY = "survey/survey_480x270.mp4"
AP_UNIX_US = 1_780_000_000_250_000
QUERY = "underwater image with fish"


def video_frames(count: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(shared_file(SURVEY)))
    frames = []
    while len(frames) < count:
        ok, image = cap.read()
        assert ok
        frames.append(image)
    cap.release()
    return frames


def pose(index: int) -> Pose:
    """Frame 0 has a valid position; frame 1 a 0/0 one (no EKF origin); frame 2 is stale (telemetry lost)."""
    lat, lon = [(1.2501, 103.8002), (0.0, 0.0), (None, None)][index]
    return Pose(time=1_700_000_000.0 + index, age_s=0.05, stale=index == 2, depth_m=4.0 + index,
                depth_source="scaled_pressure2", roll=0.1, pitch=-0.2, yaw=math.radians(90), heading_deg=90.0,
                lat=lat, lon=lon, alt_m=-4.0 - index, time_boot_ms=600_000 + 1000 * index,
                autopilot_unix_usec=AP_UNIX_US + 1_000_000 * index)


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("store")
    store = Store(StoreConfig(dir=str(folder)))
    held: list[int] = []
    for i, image in enumerate(video_frames(3)):
        frame = SummaryFrame(image_index=i, frame_index=30 * i, time_s=3.0 * i, capture_time=1_700_000_000.0 + i,
                             score=0.6 + i / 10, image=image, feature=np.ones(8, np.float32), pose=pose(i),
                             topic="main")
        held.append(i)
        store.apply(SummaryEvent("added", frame, list(held)), tags={"query": QUERY})
    return folder


def export(source: Path, fmt: str, out: Path) -> None:
    proc = run_merlion("export", str(source), "--format", fmt, "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"{out}: " in proc.stdout and f"as {fmt}" in proc.stdout


def test_fathomnet_records_read_back_with_fathomnet_py(store, tmp_path):
    dto = pytest.importorskip("fathomnet.dto")
    out = tmp_path / "fathomnet.json"
    export(store, "fathomnet", out)
    docs = json.loads(out.read_text())
    assert len(docs) == 3
    known = set(dto.Image.model_fields)  # fathomnet-py 1.10 (pydantic); the dataclass dto of older releases has the same names
    for i, doc in enumerate(docs):
        assert set(doc) <= known, set(doc) - known  # only fathomnet-py's own field names
        image = dto.Image.from_dict(doc)
        path = Path(urlparse(image.url).path)  # no --base-url: the image's own absolute file:// URL
        assert image.url.startswith("file:///") and path.is_absolute() and image.imagingType == "ROV"
        assert hashlib.sha256(path.read_bytes()).hexdigest() == image.sha256
        assert (image.width, image.height) == (480, 270) and image.mediaType == "image/jpeg"
        assert image.depthMeters == (pytest.approx(4.0 + i) if i < 2 else None)
        assert image.timestamp == ["2026-05-28T20:26:40.250Z", "2026-05-28T20:26:41.250Z",
                                   "2026-05-28T20:26:42.250Z"][i]  # the autopilot's clock, not the companion's
        tags = {t.key: t.value for t in image.tags}
        assert tags["query"] == QUERY and float(tags["score"]) == pytest.approx(0.6 + i / 10)
        assert tags["capture_utc"] == f"2023-11-14T22:13:2{i}.000Z" and int(tags["time_boot_ms"]) == 600_000 + 1000 * i
        if i < 2:
            assert float(tags["heading_deg"]) == 90.0 and float(tags["roll_deg"]) == pytest.approx(5.729578)
            assert float(tags["yaw_deg"]) == pytest.approx(90.0) and float(tags["altitude_amsl_m"]) == -4.0 - i
    assert (docs[0]["latitude"], docs[0]["longitude"]) == (1.2501, 103.8002)
    assert "latitude" not in docs[1] and "longitude" not in docs[1]  # 0/0: no position, not the Gulf of Guinea
    assert "depthMeters" not in docs[2] and "latitude" not in docs[2]  # stale: only the clocks are kept


def test_coco_loads_with_pycocotools_and_points_at_decodable_images(store, tmp_path):
    coco_module = pytest.importorskip("pycocotools.coco")
    out = tmp_path / "sub" / "coco.json"
    out.parent.mkdir()
    export(store, "coco", out)
    coco = coco_module.COCO(str(out))
    assert sorted(coco.getImgIds()) == [1, 2, 3]
    assert [c["name"] for c in coco.loadCats(coco.getCatIds())] == [QUERY]
    for img in coco.loadImgs(coco.getImgIds()):
        image = cv2.imread(str(out.parent / img["file_name"]))
        assert image is not None and image.shape[:2] == (img["height"], img["width"])
        anns = coco.loadAnns(coco.getAnnIds(imgIds=[img["id"]]))
        assert len(anns) == 1 and anns[0]["bbox"] == [0, 0, 480, 270] and anns[0]["score"] == img["score"]
        assert img.get("depth_m") == (pytest.approx(3.0 + img["id"]) if img["id"] < 3 else None) and img["dive"]
        assert img["date_captured"].startswith("2026-05-28 20:26:4")
    first, second, third = coco.loadImgs([1, 2, 3])
    assert (first["lat"], first["lon"]) == (1.2501, 103.8002) and "lat" not in second
    assert first["heading_deg"] == 90.0 and first["pitch_deg"] == pytest.approx(-11.459156)
    assert first["capture_utc"] == "2023-11-14T22:13:20.000Z" and first["time_boot_ms"] == 600_000
    assert "heading_deg" not in third and third["autopilot_utc"] == "2026-05-28T20:26:42.250Z"


def dive_rows(path: Path) -> list[dict]:
    """A VIAME CSV read the way DIVE's importer reads it (comment rows skipped, fixed columns, then species
    pairs, then ``(atr) name value``)."""
    rows = []
    for row in csv.reader(path.read_text().splitlines()):
        if not row or row[0].startswith("#"):
            continue
        pairs = [(row[i], float(row[i + 1])) for i in range(9, len(row), 2)
                 if i + 1 < len(row) and row[i] and row[i + 1] and not row[i].startswith("(")]
        attrs = {}
        for cell in row[9 + 2 * len(pairs):]:
            m = re.match(r"^\(atr\) (.*?)\s(.+)", cell)
            assert m, cell
            attrs[m[1]] = m[2]
        rows.append({"track": int(row[0]), "image": row[1], "frame": int(row[2]),
                     "box": [round(float(x)) for x in row[3:7]], "confidence": float(row[7]),
                     "length": float(row[8]), "pairs": pairs, "attrs": attrs})
    return rows


def test_viame_csv_has_dives_header_and_parses_by_its_rules(store, tmp_path):
    out = tmp_path / "dive.csv"
    export(store, "csv", out)
    assert next(csv.reader(out.read_text().splitlines())) == HEADER
    rows = dive_rows(out)
    assert [(r["track"], r["frame"]) for r in rows] == [(0, 0), (1, 1), (2, 2)]
    for i, r in enumerate(rows):
        assert cv2.imread(str(out.parent / r["image"])) is not None
        assert r["box"] == [0, 0, 480, 270] and r["length"] == -1
        assert r["pairs"] == [(QUERY, pytest.approx(0.6 + i / 10))]
        if i < 2:
            assert float(r["attrs"]["depth_m"]) == pytest.approx(4.0 + i)
        else:
            assert "depth_m" not in r["attrs"] and r["attrs"]["time_boot_ms"] == "602000"  # stale: clocks only
        assert r["attrs"]["autopilot_utc"] == f"2026-05-28T20:26:4{i}.250Z"
    assert float(rows[0]["attrs"]["lat"]) == 1.2501 and "lat" not in rows[1]["attrs"]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """A campaign folder as ``merlion archive`` leaves it: a real summarize run, tagged as the archive tags it."""
    root = tmp_path_factory.mktemp("campaign")
    dive = root / "dive1"
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(dive), "--encoder", "imagenet",
                       "--fps", "1", "-k", "3", "--threshold", "45")
    assert proc.returncode == 0, proc.stderr
    frames = json.loads((dive / "summary.json").read_text())["frames"]
    assert frames
    tags = {"tlog": "dive1.tlog", "start_time": 1_700_000_000.0, "depth_track": [], "frames": [
        {"index": f["index"], "time_s": f["time_s"], "wall_time": 1_700_000_000.0 + f["time_s"],
         "pose": Pose(time=1_700_000_000.0 + f["time_s"], age_s=0.1, stale=False, depth_m=12.5,
                      heading_deg=180.0, lat=-33.9, lon=151.2).to_dict() | {"age_s": 0.1}} for f in frames]}
    (dive / "tags.json").write_text(json.dumps(tags))
    (root / "manifest.json").write_text(json.dumps({"version": 1, "finished": {"dive1": {"key": "k"}},
                                                    "failed": {}}))
    return root


def test_summary_and_campaign_export_and_the_report_links_them(campaign, tmp_path):
    coco_module = pytest.importorskip("pycocotools.coco")
    out = tmp_path / "one_dive.json"
    export(campaign / "dive1", "coco", out)  # a summarize folder on its own
    one = coco_module.COCO(str(out))
    images = one.loadImgs(one.getImgIds())
    assert images and all(img["depth_m"] == 12.5 and img["lat"] == -33.9 and img["query"] == QUERY
                          for img in images)
    assert all(cv2.imread(str(out.parent / img["file_name"])) is not None for img in images)
    page = write_campaign_report(campaign, ["dive1"])
    html = page.read_text()
    for name in ("export_fathomnet.json", "export_coco.json", "export_viame.csv"):
        assert f"href='{name}'" in html and (campaign / name).is_file()
    whole = coco_module.COCO(str(campaign / "export_coco.json"))
    assert len(whole.getImgIds()) == len(images)
    assert all((campaign / img["file_name"]).is_file() for img in whole.loadImgs(whole.getImgIds()))
    rows = dive_rows(campaign / "export_viame.csv")
    assert len(rows) == len(images) and rows[0]["attrs"]["dive"] == "dive1"


def one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("merlion: error:"), stderr
    return lines[0]


def test_bad_input_is_one_line_and_exit_2_and_never_overwrites_the_store(store, tmp_path):
    assert FORMAT_NAMES == tuple(FORMATS)  # the command's help names what the writer writes
    cases = [
        ((str(tmp_path / "nowhere"), "--format", "coco", "--out", str(tmp_path / "x.json")), "nowhere: not a store"),
        ((str(store), "--format", "yaml", "--out", str(tmp_path / "x.json")), "--format yaml: not one of"),
        ((str(store), "--format", "coco", "--out", str(tmp_path / "no" / "x.json")), "does not exist"),
        ((str(store), "--format", "coco", "--out", str(store / "summary.json")), "would overwrite"),
        ((str(store), "--format", "csv", "--out", str(store / "lock")), "would overwrite"),
        ((str(tmp_path), "--format", "coco", "--out", str(tmp_path / "x.json")), "no summary.json"),
    ]
    before = (store / "summary.json").read_bytes()
    for args, words in cases:
        proc = run_merlion("export", *args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert words in one_error_line(proc.stderr)
    assert (store / "summary.json").read_bytes() == before
    broken = tmp_path / "broken"
    shutil.copytree(store, broken)
    (broken / "summary.json").write_text("{not json")
    proc = run_merlion("export", str(broken), "--format", "csv", "--out", str(tmp_path / "b.csv"))
    assert proc.returncode == 2 and "summary.json: not readable JSON" in one_error_line(proc.stderr)
    (broken / "frames" / "000001.jpg").unlink()
    (broken / "summary.json").write_text((store / "summary.json").read_text())
    proc = run_merlion("export", str(broken), "--format", "csv", "--out", str(tmp_path / "b.csv"))
    assert proc.returncode == 2 and "000001.jpg: frame image missing" in one_error_line(proc.stderr)
    assert not (tmp_path / "b.csv").exists()


def test_viame_csv_writes_fixed_decimals_not_rounded_or_exponent_numbers(campaign, tmp_path):
    """``.7g`` wrote lon 151.2152967 as 151.2153 (~5 m off) and a heading of ~0 as 4.720046e-10."""
    dive = tmp_path / "dive1"
    shutil.copytree(campaign / "dive1", dive)
    tags = json.loads((dive / "tags.json").read_text())
    for f in tags["frames"]:
        f["pose"] |= {"lat": -33.8567844, "lon": 151.2152967, "heading_deg": 4.720046e-10, "depth_m": 12.3456789,
                      "yaw": 4.720046e-10, "roll": -1e-12, "pitch": math.radians(-3.14159)}
    (dive / "tags.json").write_text(json.dumps(tags))
    out = tmp_path / "dive.csv"
    export(dive, "csv", out)
    attrs = dive_rows(out)[0]["attrs"]
    assert (attrs["lat"], attrs["lon"]) == ("-33.8567844", "151.2152967")
    assert (attrs["heading_deg"], attrs["yaw_deg"], attrs["roll_deg"], attrs["pitch_deg"]) == (
        "0.00", "0.00", "0.00", "-3.14")
    assert attrs["depth_m"] == "12.346"
    assert "e-" not in out.read_text()
