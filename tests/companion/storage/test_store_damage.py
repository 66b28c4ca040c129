"""Damaged files on resume: a bad feature file costs its frame alone, a next image index no MAVLink message can
carry is ignored, a bad field of summary.json costs that field alone; each with one warning line. A read-only
store says so once, not once per frame."""

from __future__ import annotations

import json
import logging
import pickle
import subprocess
from pathlib import Path

import numpy as np
import pytest

from companion.config import StoreConfig
from companion.storage.index_reservation import MAX_INDEX
from companion.storage.store import NEXT_INDEX_FILE, SUMMARY_FILE, Store
from tests.companion.conftest import tiny_tmpfs
from tests.companion.storage.test_store import added, make_frame

LOGGER = "companion.storage"


def _store(folder: Path, count: int = 4) -> Store:
    store = Store(StoreConfig(dir=str(folder)))
    for i in range(count):
        store.apply(added(make_frame(i), list(range(i + 1))))
    return store


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and r.name.startswith(LOGGER)]


def _write_npy(path: Path, array) -> None:
    with open(path, "wb") as fh:
        np.save(fh, array, allow_pickle=True)


DAMAGE = {
    "empty": lambda p: p.write_bytes(b""),
    "cut short": lambda p: p.write_bytes(p.read_bytes()[:90]),
    "random bytes": lambda p: p.write_bytes(np.random.default_rng(0).bytes(200)),
    "pickled object": lambda p: p.write_bytes(pickle.dumps({"a": 1})),
    "a matrix": lambda p: _write_npy(p, np.ones((4, 8), np.float32)),
    "strings": lambda p: _write_npy(p, np.array(["a", "b"])),
    "not finite": lambda p: _write_npy(p, np.array([1.0, np.nan], np.float32)),
    "zip archive": lambda p: np.savez(p.with_suffix(""), a=np.ones(3)) or p.with_suffix(".npz").rename(p),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_feature_file_costs_its_frame_alone(tmp_path: Path, caplog, damage: str) -> None:
    _store(tmp_path)
    DAMAGE[damage](tmp_path / "frames" / "000002.npy")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.summary == [0, 1, 3]
    assert again.next_image_index == 4
    warned = _warnings(caplog)
    assert len(warned) == 1 and "summary frame 2 dropped" in warned[0] and "000002.npy" in warned[0], warned
    for frame in again.resume_state().frames:
        assert frame.feature.shape == (32,) and frame.feature.dtype == np.float32


def test_a_sidecar_naming_another_image_costs_its_frame_alone(tmp_path: Path, caplog) -> None:
    _store(tmp_path)
    sidecar = tmp_path / "frames" / "000001.json"
    sidecar.write_text(sidecar.read_text().replace('"image_index": 1,', '"image_index": 3,'))
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.summary == [0, 2, 3]
    assert [w for w in _warnings(caplog) if "000001.json: names image 3" in w]


@pytest.mark.parametrize("claim", [10**40, 1e40, 2**31 + 1, 2.0**31, -5, "abc", True, None])
def test_a_next_image_index_no_capture_can_carry_is_ignored_and_the_rest_kept(tmp_path: Path, caplog,
                                                                              claim) -> None:
    first = _store(tmp_path)
    (tmp_path / NEXT_INDEX_FILE).unlink()  # the summary file's claim alone
    doc = json.loads((tmp_path / SUMMARY_FILE).read_text())
    doc["next_image_index"] = claim
    (tmp_path / SUMMARY_FILE).write_text(json.dumps(doc))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert (again.summary, again.next_image_index, again.dive) == ([0, 1, 2, 3], 4, first.dive)
    assert not again.memory_only
    warned = _warnings(caplog)
    assert len(warned) == 1 and "next_image_index" in warned[0] and str(MAX_INDEX) in warned[0], warned
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        Store(StoreConfig(dir=str(tmp_path)))  # the file was written again: said once, not at every start
    assert not _warnings(caplog)


def test_a_huge_next_index_record_is_ignored(tmp_path: Path, caplog) -> None:
    _store(tmp_path)
    (tmp_path / NEXT_INDEX_FILE).write_text("9" * 31 + "\n")
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert again.next_image_index == 4 and not again.memory_only
    assert len(_warnings(caplog)) == 1
    assert int((tmp_path / NEXT_INDEX_FILE).read_text()) == 4


def test_a_damaged_summary_list_is_rebuilt_and_the_dive_kept(tmp_path: Path, caplog) -> None:
    first = _store(tmp_path)
    doc = json.loads((tmp_path / SUMMARY_FILE).read_text())
    doc["summary"] = [0, "x"]
    (tmp_path / SUMMARY_FILE).write_text(json.dumps(doc))
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        again = Store(StoreConfig(dir=str(tmp_path)))
    assert (again.summary, again.dive) == ([0, 1, 2, 3], first.dive)  # from the change log
    assert len(_warnings(caplog)) == 1


def test_a_read_only_store_says_so_once_however_many_frames_follow(tmp_path: Path, caplog) -> None:
    with tiny_tmpfs(tmp_path / "ro", "size=1m") as mnt:
        _store(mnt / "store", count=2)
        assert subprocess.run(["mount", "-o", "remount,ro", str(mnt)], capture_output=True).returncode == 0
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger=LOGGER):
            store = Store(StoreConfig(dir=str(mnt / "store")))
            opened = len(_warnings(caplog))
            for i in range(2, 12):
                store.apply(added(make_frame(i), list(range(i + 1))[-6:]))
        assert store.memory_only and store.summary == list(range(6, 12))
        assert len(_warnings(caplog)) == opened == 2, _warnings(caplog)  # read-only; the run's own dive id
    with tiny_tmpfs(tmp_path / "ro-new", "size=1m,ro") as mnt:
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger=LOGGER):
            store = Store(StoreConfig(dir=str(mnt / "store")))
            for i in range(10):
                store.apply(added(make_frame(i), [i]))
        assert len(_warnings(caplog)) == 1, _warnings(caplog)
