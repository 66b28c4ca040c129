"""The on-board store: round trips on real files, resume, atomicity, the disk budget, full and read-only disks."""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

import numpy as np
import pytest

from companion.config import StoreConfig
from companion.storage.store import CHANGES_FILE, SUMMARY_FILE, TMP_PREFIX, Store
from companion.storage.versioned import NewerFileError
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.companion.conftest import tiny_tmpfs
from vehicle.autopilot.pose import Pose


def make_frame(index: int, *, size: tuple[int, int] = (96, 128), enhanced: bool = False) -> SummaryFrame:
    rng = np.random.default_rng(index)
    image = rng.integers(0, 255, size=(*size, 3), dtype=np.uint8)
    pose = Pose(time=1000.0 + index, age_s=0.05, stale=False, depth_m=3.5 + index, depth_source="global_position_int",
                roll=0.01, pitch=-0.02, yaw=1.5, q=(0.9, 0.1, 0.2, 0.3), heading_deg=86.0)
    return SummaryFrame(image_index=index, frame_index=10 * index, time_s=2.0 * index, capture_time=1000.0 + index,
                        score=0.5 + index / 100, image=image, feature=rng.random(32).astype(np.float32), pose=pose,
                        raw_image=image[::-1].copy() if enhanced else None, enhanced=enhanced)


def added(frame: SummaryFrame, summary: list[int]) -> SummaryEvent:
    return SummaryEvent("added", frame, summary)


def removed(frame: SummaryFrame, summary: list[int]) -> SummaryEvent:
    return SummaryEvent("removed", frame, summary)


def test_round_trip_and_resume_keep_frames_features_and_indices(tmp_path: Path) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    frames = [make_frame(i, enhanced=(i == 1)) for i in range(4)]
    held: list[int] = []
    for f in frames[:3]:
        held.append(f.image_index)
        store.apply(added(f, list(held)))
    held = [1, 2, 3]
    store.apply(added(frames[3], held))
    store.apply(removed(frames[0], held))
    assert store.summary == [1, 2, 3]

    again = Store(StoreConfig(dir=str(tmp_path)))
    state = again.resume_state()
    assert [f.image_index for f in state.frames] == [1, 2, 3]
    assert state.next_image_index == 4
    for got in state.frames:
        want = frames[got.image_index]
        np.testing.assert_array_equal(got.feature, want.feature)
        assert got.image.shape == want.image.shape
        assert got.frame_index == want.frame_index and got.score == pytest.approx(want.score)
        assert got.pose == want.pose
    assert state.frames[0].enhanced and state.frames[0].raw_image is not None
    side = again.sidecar(2)
    assert side["pose"]["depth_m"] == pytest.approx(5.5) and side["file"] == "frames/000002.jpg"
    # the trimmed frame stays on disk until the budget needs the room, and can still be fetched by index
    assert again.frame(0) is not None
    log = [json.loads(line) for line in (tmp_path / CHANGES_FILE).read_text().splitlines()]
    assert [e["kind"] for e in log] == ["added"] * 4 + ["removed"]
    assert not list(tmp_path.rglob(f"{TMP_PREFIX}*"))


def test_next_index_never_reused_even_when_the_summary_file_lags(tmp_path: Path) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(0), [0]))
    store.apply(added(make_frame(1), [0, 1]))
    # a crash after the frame files were written but before summary.json: simulate with an older summary.json
    doc = json.loads((tmp_path / SUMMARY_FILE).read_text())
    doc["summary"], doc["next_image_index"] = [0], 1
    (tmp_path / SUMMARY_FILE).write_text(json.dumps(doc))
    again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.summary == [0]
    assert again.next_image_index == 2


def test_half_written_files_are_removed_and_a_broken_index_is_rebuilt(tmp_path: Path) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(0), [0]))
    store.apply(added(make_frame(1), [0, 1]))
    (tmp_path / "frames" / f"{TMP_PREFIX}000002.jpg.123").write_bytes(b"\xff\xd8 half")
    (tmp_path / SUMMARY_FILE).write_text('{"summary": [0, 1')  # torn by hand: atomic writes never leave this
    with open(tmp_path / CHANGES_FILE, "a") as fh:
        fh.write('{"kind": "added", "summ')  # a log line cut short by a crash
    again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.summary == [0, 1]
    assert not list(tmp_path.rglob(f"{TMP_PREFIX}*"))


def test_valid_json_of_the_wrong_shape_drops_only_what_it_damaged(tmp_path: Path) -> None:
    """Hand-edited or damaged files that still parse as JSON: the store starts (no boot loop under systemd)."""
    store = Store(StoreConfig(dir=str(tmp_path)))
    for i in range(3):
        store.apply(added(make_frame(i), list(range(i + 1))))
    (tmp_path / SUMMARY_FILE).write_text("[0, 1, 2]")  # an array, not an object
    with open(tmp_path / CHANGES_FILE, "a") as fh:
        fh.write('{"kind": "added", "summary": ["x"]}\n')
    (tmp_path / "frames" / "000001.json").write_text('{"no": "image_index"}')
    (tmp_path / "frames" / "000002.json").write_text("[]")
    again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.summary == [0]
    assert again.next_image_index == 3


def test_disk_budget_prunes_oldest_non_summary_frames_first(tmp_path: Path) -> None:
    cfg = StoreConfig(dir=str(tmp_path), disk_budget_mb=0.25)
    store = Store(cfg)
    summary: list[int] = []
    for i in range(12):
        frame = make_frame(i, size=(120, 160))
        summary = (summary + [i])[-3:]
        store.apply(added(frame, summary))
    assert store.stats.frames_pruned > 0
    on_disk = {int(p.name[:6]) for p in (tmp_path / "frames").glob("*.json")}
    assert set(summary) <= on_disk
    assert 0 not in on_disk  # the oldest went first
    assert store.stats.bytes_on_disk <= cfg.disk_budget_mb * 1024 * 1024


def test_full_disk_degrades_to_memory_and_keeps_what_was_saved(tmp_path: Path, caplog) -> None:
    with tiny_tmpfs(tmp_path / "small", "size=160k") as mnt:
        store = Store(StoreConfig(dir=str(mnt)))
        summary: list[int] = []
        for i in range(30):
            summary = (summary + [i])[-6:]
            store.apply(added(make_frame(i, size=(200, 260)), summary))
        assert store.memory_only and store.memory_only_reason == "disk full"
        assert store.summary == summary  # the live summary goes on in memory
        assert "memory only" in caplog.text
        again = Store(StoreConfig(dir=str(mnt)))
        state = again.resume_state()
        assert state.frames, "frames saved before the disk filled are readable"
        for f in state.frames:
            assert f.image is not None and f.feature.shape == (32,)


def test_read_only_store_dir_runs_memory_only(tmp_path: Path) -> None:
    first = tmp_path / "ro"
    if os.geteuid() == 0:
        ctx = tiny_tmpfs(first, "size=1m,ro")
    else:
        first.mkdir()
        first.chmod(0o555)
        ctx = contextlib.nullcontext(first)
    with ctx as mnt:
        store = Store(StoreConfig(dir=str(mnt / "store")))
        assert store.memory_only
        store.apply(added(make_frame(0), [0]))
        assert store.summary == [0] and store.frame(0) is not None


def test_store_path_that_is_a_file_degrades_with_a_warning(tmp_path: Path, caplog) -> None:
    target = tmp_path / "not-a-dir"
    target.write_text("x")
    store = Store(StoreConfig(dir=str(target)))
    assert store.memory_only
    store.apply(added(make_frame(0), [0]))
    assert store.summary == [0]
    assert target.read_text() == "x"


def test_a_torn_change_line_is_cut_so_the_next_run_logs_whole_lines(tmp_path: Path) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(0), [0]))
    with open(tmp_path / CHANGES_FILE, "a") as fh:
        fh.write('{"kind": "added", "summ')  # killed in the middle of a line
    again = Store(StoreConfig(dir=str(tmp_path)))
    again.apply(added(make_frame(1), [0, 1]))
    lines = [json.loads(line) for line in (tmp_path / CHANGES_FILE).read_text().splitlines()]
    assert [e["image_index"] for e in lines] == [0, 1]


def test_a_store_written_by_a_newer_version_is_refused_and_left_untouched(tmp_path: Path) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(0), [0]))
    index = tmp_path / SUMMARY_FILE
    doc = json.loads(index.read_text())
    doc["version"] = 7
    index.write_text(json.dumps(doc))
    before = index.read_bytes()
    with pytest.raises(NewerFileError, match=rf"{SUMMARY_FILE}: written in format version 7, but .* reads format "
                                             r"version 1 at most"):
        Store(StoreConfig(dir=str(tmp_path)))
    assert index.read_bytes() == before


def test_space_reports_the_budget_its_files_and_the_room_left(tmp_path: Path) -> None:
    """What STORAGE_INFORMATION says (QGroundControl shows it as the camera's free space): never more than the
    budget's rest, nor than the file system has; nothing at all once the disk is full and the store in memory."""
    store = Store(StoreConfig(dir=str(tmp_path / "store"), disk_budget_mb=4.0))
    empty = store.space()
    assert empty.total == 4 * 1024 * 1024 and empty.available == empty.total - empty.used
    store.apply(added(make_frame(0), [0]))
    space = store.space()
    assert space.used > empty.used and space.available == space.total - space.used
    with tiny_tmpfs(tmp_path / "small", "size=160k") as mnt:
        small = Store(StoreConfig(dir=str(mnt), disk_budget_mb=4.0))
        assert small.space().available <= 160 * 1024  # the file system's free space, below the budget's rest
        summary: list[int] = []
        for i in range(30):
            summary = (summary + [i])[-6:]
            small.apply(added(make_frame(i, size=(200, 260)), summary))
        assert small.memory_only and small.space().available == 0


def test_a_frame_that_is_a_link_is_not_served(tmp_path: Path) -> None:
    """What the surface downloads over FTP is the store's own file: a link in frames/ is not followed."""
    store = Store(StoreConfig(dir=str(tmp_path / "store")))
    store.apply(added(make_frame(0), [0]))
    store.apply(added(make_frame(1), [0, 1]))
    assert store.frame_jpeg(0)[:2] == b"\xff\xd8"  # a JPEG, as written
    secret = tmp_path / "secret.txt"
    secret.write_bytes(b"not for the link")
    jpg = tmp_path / "store" / "frames" / "000001.jpg"
    jpg.unlink()
    jpg.symlink_to(secret)
    assert store.frame_jpeg(1) is None and store.frame_jpeg(0)[:2] == b"\xff\xd8"
