"""The HTML report: its PNGs exist, are real images, and the page references each of them."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np

from companion.evaluation.report import ReportRun, write_report
from companion.evaluation.runs import run_from_summary


def _frame(value: int) -> np.ndarray:
    img = np.zeros((60, 100, 3), np.uint8)
    img[:, :, value % 3] = 40 + value
    return img


def test_report_with_pictures_scores_and_depth(tmp_path):
    run = ReportRun(
        name="MERLION (imagenet)",
        metrics={"precision": 0.8333, "coverage": 1.0, "frames": [3, 15]},
        frame_times=[0.3, 1.5], frame_labels=["#2", "#14"], images=[_frame(1), _frame(2)],
        frame_depths=[2.5, None], score_times=[0.1 * i for i in range(30)],
        scores=[0.5 + 0.4 * np.sin(i / 4) for i in range(30)], tau=0.5,
        depth_times=[0.0, 1.0, 2.0, 3.0], depths=[0.0, 2.0, 3.0, 3.5],
    )
    bare = ReportRun(name="baseline", metrics={"precision": 0.5})
    page = write_report(tmp_path / "rep", [run, bare])
    text = page.read_text()
    refs = re.findall(r"src='([^']+)'", text)
    assert sorted(refs) == ["merlion_imagenet_contact_sheet.png", "merlion_imagenet_depth.png",
                            "merlion_imagenet_score.png"]
    for ref in refs:
        img = cv2.imread(str(page.parent / ref))
        assert img is not None and img.shape[0] > 50 and img.shape[1] > 50
    assert sorted(p.name for p in page.parent.glob("*.png")) == sorted(refs)
    assert "0.8333" in text and "<th>baseline</th>" in text and "No depth tags" in text


def test_run_from_summary_reads_pictures_and_depth_tags(tmp_path):
    for i in (4, 9):
        cv2.imwrite(str(tmp_path / f"f{i}.jpg"), _frame(i))
    summary = {"frames": [{"index": 4, "time_s": 0.4, "score": 0.9, "file": "f4.jpg", "pose": {"depth_m": 3.2}},
                          {"index": 9, "time_s": 0.9, "score": 0.8, "file": "f9.jpg"}]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    run = run_from_summary("s", summary, tmp_path, {"srum": 0.5})
    assert len(run.images) == 2 and run.frame_depths == [3.2, None] and run.frame_times == [0.4, 0.9]
    page = write_report(tmp_path / "out", [run])
    assert (page.parent / "s_contact_sheet.png").is_file() and (page.parent / "s_depth.png").is_file()


def test_store_summary_with_pose_tags_gives_a_depth_profile(tmp_path):
    from companion.config import StoreConfig
    from companion.evaluation.datasets import read_summary_json
    from companion.storage.store import Store
    from companion.vision.events import SummaryEvent, SummaryFrame
    from vehicle.autopilot.pose import Pose

    store = Store(StoreConfig(), directory=tmp_path / "store")
    held: list[int] = []
    for n, (index, depth) in enumerate([(14, 2.0), (40, 3.5), (70, None)]):
        pose = Pose(time=100.0 + n, age_s=0.05, stale=depth is None, depth_m=depth)
        frame = SummaryFrame(image_index=n, frame_index=index, time_s=index / 10, capture_time=1.7e9 + n,
                             score=0.8, image=_frame(n), feature=np.ones(4, np.float32) / 4, pose=pose)
        held.append(n)
        store.apply(SummaryEvent("added", frame, list(held)))
    frames, doc = read_summary_json(tmp_path / "store" / "summary.json")
    assert frames == [15, 41, 71]
    run = run_from_summary("live", doc, tmp_path / "store", {"frames": frames})
    assert run.frame_depths == [2.0, 3.5, None] and len(run.images) == 3
    page = write_report(tmp_path / "rep", [run])
    assert "live_depth.png" in page.read_text() and cv2.imread(str(tmp_path / "rep" / "live_depth.png")) is not None
