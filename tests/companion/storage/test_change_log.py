"""The change log is never left with a torn line: a real full tmpfs and a real file-size limit (EFBIG) each take
part of a line and refuse the rest; the log is cut back to its last whole line, and later lines stand alone."""

from __future__ import annotations

import errno
import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.storage.change_log import ChangeLog
from tests.companion.conftest import fill_disk, tiny_tmpfs
from tests.conftest import REPO


def _entries(path: Path) -> list[dict]:
    data = path.read_bytes()
    assert data.endswith(b"\n"), f"torn tail: {data[-60:]!r}"
    return [json.loads(line) for line in data.decode().splitlines()]


def test_an_append_the_full_disk_takes_only_part_of_is_cut_back(tmp_path: Path) -> None:
    with tiny_tmpfs(tmp_path / "small", "size=64k") as mnt:
        log = ChangeLog(mnt / "changes.jsonl")
        n = 0
        while n == 0 or (mnt / "changes.jsonl").stat().st_size < 3900:  # up to near the end of its first page
            log.append({"kind": "added", "image_index": n, "summary": [n]})
            n += 1
        before = (mnt / "changes.jsonl").read_bytes()
        fill_disk(mnt / "filler")
        with pytest.raises(OSError) as refused:
            log.append({"kind": "added", "image_index": n, "summary": list(range(100))})  # past the page
        assert refused.value.errno == errno.ENOSPC
        assert (mnt / "changes.jsonl").read_bytes() == before
        (mnt / "filler").unlink()
        log.append({"kind": "back_on_disk", "summary": [n - 1]})
        entries = _entries(mnt / "changes.jsonl")
        assert [e.get("image_index") for e in entries] == [*range(n), None]
        assert log.last_summary() == [n - 1]


WRITER = """
import resource, sys
import numpy as np
from companion.config import StoreConfig
from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame

store = Store(StoreConfig(dir=sys.argv[1]))
resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))  # every file a frame writes stays under it; the log grows
for i in range(200):
    image = np.full((8, 8, 3), i, np.uint8)
    frame = SummaryFrame(i, i, float(i), 1000.0 + i, 0.5, image, np.ones(4, np.float32))
    store.apply(SummaryEvent("added", frame, [i]))
    if store.memory_only:
        print(store.memory_only_reason, i)
        break
"""


def test_a_store_whose_log_meets_a_file_size_limit_keeps_whole_lines(tmp_path: Path) -> None:
    store = tmp_path / "store"
    done = subprocess.run([sys.executable, "-c", WRITER, str(store)], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("File too large "), done.stdout + done.stderr
    last = int(done.stdout.split()[-1])
    path = store / "changes.jsonl"
    entries = _entries(path)
    assert path.stat().st_size <= 2000
    assert [e["image_index"] for e in entries] == list(range(last))  # the refused frame's line is not there
