"""The store's lock between processes: a real second process holds it, is refused by name and pid, and the kernel
frees it when the holder is killed with SIGKILL (no stale lock to clear by hand)."""

from __future__ import annotations

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
