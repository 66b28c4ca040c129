"""The store at the end of the image indices MAVLink carries (int32: 0-2147483647), on real files: the next index
may be one past the last (every index used) and stays there across restarts; a store left by a run from before
the limit, with frames past it, is never written over; the disk budget prunes frames of any number of digits."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

from companion.config import StoreConfig
from companion.storage.index_reservation import MAX_INDEX, USED_UP
from companion.storage.store import CHANGES_FILE, NEXT_INDEX_FILE, SUMMARY_FILE, Store
from tests.companion.storage.test_store import added, make_frame


def _errors(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


def test_the_last_index_leaves_the_store_used_up_across_restarts(tmp_path: Path, caplog) -> None:
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(MAX_INDEX - 1), [MAX_INDEX - 1]))
    store.apply(added(make_frame(MAX_INDEX), [MAX_INDEX - 1, MAX_INDEX]))
    assert store.next_image_index == USED_UP == 2**31
    with caplog.at_level(logging.WARNING, logger="companion.storage"):
        store.apply(added(make_frame(USED_UP), [MAX_INDEX - 1, MAX_INDEX, USED_UP]))  # a last guard: refused
    assert any(f"image index {USED_UP} not stored" in e for e in _errors(caplog))
    assert store.summary == [MAX_INDEX - 1, MAX_INDEX] and not (tmp_path / "frames" / f"{USED_UP}.json").exists()
    assert json.loads((tmp_path / SUMMARY_FILE).read_text())["next_image_index"] == USED_UP

    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="companion.storage"):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert (again.summary, again.next_image_index, again.dive) == ([MAX_INDEX - 1, MAX_INDEX], USED_UP, store.dive)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert not warnings, warnings  # before: "not a list of image indices", "not one MAVLink can announce"
    (error,) = _errors(caplog)
    assert "every image index MAVLink can carry (0-2147483647) is used" in error and "move the store aside" in error


def test_a_used_up_store_whose_last_frames_were_pruned_hands_out_nothing_again(tmp_path: Path) -> None:
    """The records alone say every index was used: the frames on disk no longer reach the last one."""
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(5), [5]))
    store.apply(added(make_frame(MAX_INDEX), [5]))  # trimmed at once
    for suffix in ("jpg", "npy", "json"):
        (tmp_path / "frames" / f"{MAX_INDEX}.{suffix}").unlink()  # pruned for the disk budget
    assert Store(StoreConfig(dir=str(tmp_path))).next_image_index == USED_UP
    (tmp_path / SUMMARY_FILE).unlink()  # next_index alone
    assert Store(StoreConfig(dir=str(tmp_path))).next_image_index == USED_UP


def test_frames_past_the_limit_left_by_an_older_run_are_never_written_over(tmp_path: Path, caplog) -> None:
    """What a run from before the limit left: frames 2147483648 and up, in the summary and the change log, and
    next-index records past the limit. Before, the next start ignored all of that and numbered from 2147483648
    again (the highest valid frame on disk plus one), writing over those frames."""
    store = Store(StoreConfig(dir=str(tmp_path)))
    store.apply(added(make_frame(7), [7]))
    store.apply(added(make_frame(MAX_INDEX), [7, MAX_INDEX]))
    frames = tmp_path / "frames"
    for index in (USED_UP, USED_UP + 1):  # written as the older run wrote them
        for suffix in ("jpg", "npy"):
            shutil.copy(frames / f"{MAX_INDEX}.{suffix}", frames / f"{index}.{suffix}")
        sidecar = json.loads((frames / f"{MAX_INDEX}.json").read_text())
        sidecar["image_index"] = index
        (frames / f"{index}.json").write_text(json.dumps(sidecar))
    for suffix in ("jpg", "npy", "json"):  # the last valid one trimmed and pruned since
        (frames / f"{MAX_INDEX}.{suffix}").unlink()
    held = [7, USED_UP, USED_UP + 1]
    doc = json.loads((tmp_path / SUMMARY_FILE).read_text())
    doc.update(summary=held, next_image_index=USED_UP + 2)
    (tmp_path / SUMMARY_FILE).write_text(json.dumps(doc))
    with open(tmp_path / CHANGES_FILE, "a") as fh:
        fh.write(json.dumps({"kind": "added", "image_index": USED_UP + 1, "summary": held}) + "\n")
    (tmp_path / NEXT_INDEX_FILE).write_bytes(f"{USED_UP + 2:>31d}\n".encode())
    before = {p.name: p.read_bytes() for p in frames.iterdir()}

    with caplog.at_level(logging.WARNING, logger="companion.storage"):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.next_image_index == USED_UP and again.summary == [7]
    assert any("2147483648, 2147483649] dropped from the summary" in r.getMessage() for r in caplog.records)
    again.apply(added(make_frame(USED_UP), [7, USED_UP]))  # what the old pipeline would offer: refused
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before
    assert json.loads((tmp_path / SUMMARY_FILE).read_text())["summary"] == [7]


def test_the_disk_budget_prunes_frames_of_seven_digits_and_more(tmp_path: Path) -> None:
    """Before, the budget read an index from the first six characters of a name: frame 1000000 was taken for
    100000, never pruned, and the store grew past its budget."""
    cfg = StoreConfig(dir=str(tmp_path), disk_budget_mb=0.25)
    store = Store(cfg)
    summary: list[int] = []
    first = 1_000_000
    for index in range(first, first + 20):
        summary = (summary + [index])[-3:]
        store.apply(added(make_frame(index, size=(120, 160)), summary))
    on_disk = {int(p.name.split(".")[0]) for p in (tmp_path / "frames").glob("*.json")}
    assert set(summary) <= on_disk and first not in on_disk  # the oldest went first
    assert store.stats.bytes_on_disk <= cfg.disk_budget_mb * 1024 * 1024
    assert sum(p.stat().st_size for p in tmp_path.rglob("*") if p.is_file()) <= cfg.disk_budget_mb * 1024 * 1024
