"""Issue 46 item 2: a store that cannot persist its next image index, for any reason and at any time, announces
under a new dive id from that frame on, says so once, and no (dive, index) pair is ever announced twice, whether
the disk comes back during the run or only after it. The companion announces a frame after ``Store.apply``, under
``Store.dive`` as it is then; these tests record the pairs the same way."""

from __future__ import annotations

import logging
import subprocess
from pathlib import Path

import pytest

from companion.config import StoreConfig
from companion.storage.store import NEXT_INDEX_FILE, Store
from tests.companion.conftest import tiny_tmpfs
from tests.companion.storage.test_store import added, make_frame


class Run:
    """One run of the store: frames added in index order, every (dive, index) pair it announced kept."""

    def __init__(self, directory: Path) -> None:
        self.store = Store(StoreConfig(dir=str(directory)))
        self.store.health.retry_s = 0.0  # the disk is tried again at every frame, not every 5 s
        self.announced: list[tuple[str, int]] = []

    def add(self, count: int) -> None:
        for _ in range(count):
            index = self.store.next_image_index
            self.store.apply(added(make_frame(index), (self.store.summary + [index])[-4:]))
            self.announced.append((self.store.dive, index))


def _dives(run: Run) -> list[str]:
    return list(dict.fromkeys(d for d, _ in run.announced))


def _break_index_file(directory: Path) -> None:
    """The next-index record cannot be written, while the rest of the folder can (any cause: here a directory
    where the file was, so it fails without root)."""
    (directory / NEXT_INDEX_FILE).unlink()
    (directory / NEXT_INDEX_FILE).mkdir()


def _repair_index_file(directory: Path) -> None:
    (directory / NEXT_INDEX_FILE).rmdir()


def test_an_index_file_that_cannot_be_written_mid_run_gives_a_new_dive_at_once_said_once(tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="companion.storage.store")
    first = Run(tmp_path / "store")
    first.add(5)
    _break_index_file(first.store.dir)
    first.add(6)  # the run ends here, the record still broken: what it announced after index 4 was never reserved
    dives = _dives(first)
    assert len(dives) == 2 and first.announced[5] == (dives[1], 5)  # the new dive from the very frame that failed
    assert first.store.dive_changes == 1 and first.store.memory_only
    said = [r.message for r in caplog.records if "cannot be persisted" in r.message]
    assert len(said) == 1 and f"new dive id {dives[1]}" in said[0] and "from 5 on" in said[0], said
    _repair_index_file(first.store.dir)
    second = Run(first.store.dir)  # the next run, after repair, resumes the old dive from the last saved index
    second.add(5)
    assert second.store.dive == dives[0]
    pairs = first.announced + second.announced
    assert len(set(pairs)) == len(pairs), pairs  # the issue: 22 pairs announced twice


def test_a_repair_during_the_run_persists_the_new_dive_and_a_second_failure_takes_another(tmp_path):
    run = Run(tmp_path / "store")
    run.add(3)
    _break_index_file(run.store.dir)
    run.add(3)
    _repair_index_file(run.store.dir)
    run.add(3)  # the first of these finds the disk writable again: back on disk, under the new dive
    assert not run.store.memory_only and run.store.dive_changes == 1
    assert int((run.store.dir / NEXT_INDEX_FILE).read_text()) == 9
    on_disk = Store(StoreConfig(dir=str(run.store.dir)))
    assert on_disk.dive == _dives(run)[1] and on_disk.next_image_index == 9
    _break_index_file(run.store.dir)
    run.add(2)
    assert run.store.dive_changes == 2 and len(_dives(run)) == 3
    _repair_index_file(run.store.dir)
    after = Run(run.store.dir)  # resumes the second dive, from the index its last reservation holds
    after.add(3)
    assert after.store.dive == _dives(run)[1]
    pairs = run.announced + after.announced
    assert len(set(pairs)) == len(pairs), pairs


def _remount(mnt: Path, mode: str) -> None:
    done = subprocess.run(["mount", "-o", f"remount,{mode}", str(mnt)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot remount a tmpfs {mode} here: {done.stderr.strip()}")


def test_the_kernels_read_only_remount_mid_run_never_reuses_a_pair_after_repair(tmp_path):
    """The issue's case on a real filesystem (a tmpfs remounted read-only under the running store, as the
    kernel's emergency remount does): 22 pairs had been announced twice by the next run after repair."""
    with tiny_tmpfs(tmp_path / "mnt", "size=4m") as mnt:
        first = Run(mnt / "store")
        first.add(6)
        _remount(mnt, "ro")
        first.add(8)  # the run ends read-only
        assert first.store.memory_only and first.store.memory_only_reason == "read-only file system"
        assert first.store.dive_changes == 1 and first.announced[6][0] != first.announced[5][0]
        _remount(mnt, "rw")
        second = Run(mnt / "store")
        second.add(6)
        pairs = first.announced + second.announced
        assert len(set(pairs)) == len(pairs), pairs
        assert second.store.dive == first.announced[0][0] and second.announced[0][1] == 6
        # and a remount that is repaired while the run goes on: back on disk under the dive it announced
        _remount(mnt, "ro")
        second.add(2)
        _remount(mnt, "rw")
        second.add(2)
        assert not second.store.memory_only and second.store.dive_changes == 1
        third = Run(mnt / "store")
        third.add(2)
        assert third.store.dive == second.store.dive
        pairs = first.announced + second.announced + third.announced
        assert len(set(pairs)) == len(pairs), pairs
