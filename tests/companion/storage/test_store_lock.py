"""The store's lock between processes: a real second process holds it, is refused by name and pid, and the kernel
frees it when the holder is killed with SIGKILL (no stale lock to clear by hand)."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from companion.storage.store_lock import LOCK_FILE, StoreInUse, StoreLock, check_free
from tests.companion.conftest import tiny_tmpfs
from tests.conftest import REPO

HOLD = """
import sys, time
from companion.storage.store_lock import StoreLock
StoreLock(sys.argv[1]).acquire()
print("held", flush=True)
time.sleep(120)
"""


def _holder(store: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(store)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_held_store_is_refused_naming_the_holder_and_freed_by_sigkill(tmp_path: Path) -> None:
    store = tmp_path / "store"
    proc = _holder(store)
    try:
        with pytest.raises(StoreInUse, match=rf"store {store}: in use by pid {proc.pid} "):
            StoreLock(store).acquire()
        with pytest.raises(StoreInUse, match=rf"pid {proc.pid}"):
            check_free(store)
    finally:
        proc.kill()
        proc.wait(10)
    lock = StoreLock(store)
    lock.acquire()  # the kernel dropped the killed holder's lock
    assert lock.held
    with pytest.raises(StoreInUse):
        check_free(store)  # held by this process now: any other open of the lock file is refused
    lock.release()
    check_free(store)


def test_check_free_creates_nothing(tmp_path: Path) -> None:
    check_free(tmp_path / "none")
    assert not (tmp_path / "none").exists()


def test_a_read_only_store_runs_without_a_lock_or_with_the_one_left_there(tmp_path: Path) -> None:
    with tiny_tmpfs(tmp_path / "ro", "size=1m,ro") as mnt:
        lock = StoreLock(mnt / "store")
        lock.acquire()  # cannot make a lock file: no lock, no error (such a store writes nothing)
        assert not lock.held
    with tiny_tmpfs(tmp_path / "was", "size=1m") as mnt:
        earlier = StoreLock(mnt)  # an earlier run made the lock file
        earlier.acquire()
        earlier.release()
        assert (mnt / LOCK_FILE).is_file()
        assert subprocess.run(["mount", "-o", "remount,ro", str(mnt)], capture_output=True).returncode == 0
        proc = _holder(mnt)
        try:
            with pytest.raises(StoreInUse, match="in use by"):
                StoreLock(mnt).acquire()
        finally:
            proc.kill()
            proc.wait(10)


@pytest.mark.parametrize("swap", ["lock file removed", "lock file replaced", "folder replaced"])
def test_a_store_whose_lock_is_taken_from_under_it_writes_nothing_more(tmp_path: Path, swap: str, caplog) -> None:
    """Before, the lock guarded a file the path no longer led to: a second process locked the new one and both
    wrote the same folder (this store its next_index, frames, summary.json and change log into the other's)."""
    from companion.config import StoreConfig
    from companion.storage.params_file import ParamsFile
    from companion.storage.store import Store
    from tests.companion.storage.test_store import added, make_frame

    store_dir = tmp_path / "store"
    lock = StoreLock(store_dir)
    lock.acquire()
    store = Store(StoreConfig(dir=str(store_dir)), guard=lock.check)
    store.apply(added(make_frame(0), [0]))
    lock.check()  # still ours
    if swap == "lock file removed":
        (store_dir / LOCK_FILE).unlink()
    elif swap == "lock file replaced":
        (store_dir / LOCK_FILE).rename(tmp_path / "old-lock")
        (store_dir / LOCK_FILE).write_text("")
    else:
        store_dir.rename(tmp_path / "store.old")
        store_dir.mkdir()
    other = _holder(store_dir)  # a second process takes the path's lock: the store there is its store now
    try:
        before = {p.name: p.read_bytes() for p in store_dir.rglob("*") if p.is_file() and p.name != LOCK_FILE}
        with caplog.at_level(logging.WARNING, logger="companion.storage.store"):
            store.apply(added(make_frame(1), [0, 1]))
            store.apply(added(make_frame(2), [0, 1, 2]))
        assert store.memory_only and store.memory_only_reason == "folder replaced"
        assert store.summary == [0, 1, 2] and store.frame(2) is not None  # the run goes on, in memory
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and f"store {store_dir}: replaced under this run" in errors[0], errors
        assert "writes nothing more there" in errors[0]
        store.health.clock = lambda: 1e12  # long past any retry: a replaced store never comes back on disk
        assert not store.retry()
        assert not ParamsFile(store_dir / "params.json", guard=lock.check).save({"X": 1.0})
        after = {p.name: p.read_bytes() for p in store_dir.rglob("*") if p.is_file() and p.name != LOCK_FILE}
        assert after == before, "written into the folder another process holds"
    finally:
        other.kill()
        other.wait(10)
        lock.release()
