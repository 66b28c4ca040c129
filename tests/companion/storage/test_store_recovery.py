"""A store on a real tiny tmpfs: full, then freed; read-only from the start. It says so once to its listeners,
goes back to disk with what it kept in memory, and never hands an image index out twice under one dive id."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from companion.config import StoreConfig
from companion.storage.params_file import ParamsFile
from companion.storage.store import NEXT_INDEX_FILE, SUMMARY_FILE, Store
from tests.companion.conftest import fill_disk, tiny_tmpfs
from tests.companion.storage.test_store import added, make_frame


def _until_memory_only(store: Store, start: int) -> int:
    index = start
    summary = list(store.summary)
    while not store.memory_only:
        summary = (summary + [index])[-6:]
        store.apply(added(make_frame(index, size=(200, 260)), summary))
        index += 1
        assert index < start + 200, "the tiny disk never filled"
    return index


def test_a_full_store_says_so_once_and_goes_back_to_disk_when_space_returns(tmp_path: Path) -> None:
    with tiny_tmpfs(tmp_path / "small", "size=1m") as mnt:
        store = Store(StoreConfig(dir=str(mnt / "store")))
        heard: list[tuple[bool, str]] = []
        store.on_health(lambda memory_only, reason: heard.append((memory_only, reason)))
        store.health.retry_s = 0.0  # every apply and retry() tries the disk (the companion: every 5 s)
        fill_disk(mnt / "filler")
        index = _until_memory_only(store, 0)
        for i in range(index, index + 5):  # frames kept in memory only; each retry still fails
            store.apply(added(make_frame(i, size=(200, 260)), (store.summary + [i])[-6:]))
        assert heard == [(True, "disk full")]  # once, however many writes failed
        in_memory = store.describe()["frames_in_memory_only"]
        assert in_memory > 0
        (mnt / "filler").unlink()
        assert store.retry()
        assert heard == [(True, "disk full"), (False, "")]
        assert not store.memory_only and store.describe()["frames_in_memory_only"] == 0
        on_disk = json.loads((store.dir / SUMMARY_FILE).read_text())
        assert on_disk["summary"] == store.summary
        for i in store.summary:
            assert (store.frames_dir / f"{i:06d}.json").is_file() and (store.frames_dir / f"{i:06d}.jpg").is_file()
        resumed = Store(StoreConfig(dir=str(store.dir)))
        assert resumed.summary == store.summary and resumed.dive == store.dive


def test_no_image_index_is_reused_after_a_run_that_ended_with_the_disk_full(tmp_path: Path) -> None:
    with tiny_tmpfs(tmp_path / "small", "size=1m") as mnt:
        store = Store(StoreConfig(dir=str(mnt / "store")))
        fill_disk(mnt / "filler")
        index = _until_memory_only(store, 0)
        announced = list(range(index, index + 20))  # what the surface heard while the disk was full
        for i in announced:
            store.apply(added(make_frame(i, size=(200, 260)), (store.summary + [i])[-6:]))
        assert json.loads((store.dir / SUMMARY_FILE).read_text())["next_image_index"] < announced[-1]
        # the run ends (no recovery); the next one opens the same full disk
        again = Store(StoreConfig(dir=str(store.dir)))
        assert again.dive == store.dive
        assert again.next_image_index > announced[-1]
        assert int((store.dir / NEXT_INDEX_FILE).read_text()) == announced[-1] + 1


def test_a_store_read_only_from_the_start_takes_a_dive_id_of_its_own(tmp_path: Path) -> None:
    where = tmp_path / "ro"
    with tiny_tmpfs(where, "size=1m") as mnt:
        first = Store(StoreConfig(dir=str(mnt / "store")))
        first.apply(added(make_frame(0), [0]))
        assert subprocess.run(["mount", "-o", "remount,ro", str(mnt)], capture_output=True).returncode == 0
        second = Store(StoreConfig(dir=str(mnt / "store")))
        assert second.memory_only and second.memory_only_reason == "read-only file system"
        assert second.summary == [0] and second.next_image_index == 1
        assert second.dive != first.dive  # what it announces cannot be confused with what a lost run announced
        assert not ParamsFile(mnt / "store" / "params.json").save({"MERL_K": 4.0})  # refused, no exception
