"""Issue 46 item 2 end to end: `merlion run` whose store can no longer persist its next image index mid-run
announces under a new dive id from that frame on and tells the surface (one STATUSTEXT), and after repair the next
run never announces a (dive, index) pair the first one announced. The record is made unwritable by a directory
standing where the file was (no root needed; tests/companion/storage/test_store_dive_index.py remounts a real
filesystem read-only under a store)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from companion.storage.store import NEXT_INDEX_FILE
from tests.companion.live_harness import Companion, wait_until, write_config

NEW_DIVE = "Index not saved: new dive id"
_URL = re.compile(r"/summary/([0-9a-f]+)/(\d+)\.")


def _captures(listener, start: int = 0) -> list:
    return [m for m in listener.messages[start:]
            if m.get_type() == "CAMERA_IMAGE_CAPTURED" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)]


def _pair(msg) -> tuple[str, int]:
    url = msg.file_url if isinstance(msg.file_url, str) else msg.file_url.decode()
    found = _URL.search(url)
    assert found is not None and int(found.group(2)) == msg.image_index, url
    return found.group(1), msg.image_index


@pytest.mark.slow
def test_an_index_that_cannot_be_persisted_mid_run_means_a_new_dive_said_once_and_no_pair_twice(tmp_path: Path,
                                                                                                 dive) -> None:
    hub, _gcs, listener = dive
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       sampler={"k": 4}, source={"uri": "synthetic://dive?seconds=2&width=320&height=240"})
    first = Companion("--config", str(cfg))
    first.wait_for("companion running")
    wait_until(lambda: len(_captures(listener)) >= 2, 60, "captures before the failure")
    old_dive = _pair(_captures(listener)[0])[0]
    (store / NEXT_INDEX_FILE).unlink()
    (store / NEXT_INDEX_FILE).mkdir()  # the record cannot be written from now on (the rest of the store can)
    said = listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and NEW_DIVE in str(m.text), 90, NEW_DIVE)
    assert said.severity == 4  # MAV_SEVERITY_WARNING
    new_dive = str(said.text).split()[-1]
    assert new_dive != old_dive
    mark = len(listener.messages)
    wait_until(lambda: len(_captures(listener, mark)) >= 2, 90, "captures after the failure")
    assert {_pair(m)[0] for m in _captures(listener, mark)} == {new_dive}
    first.kill()  # ends while the record is still unwritable
    first.wait_for("cannot be persisted")  # the log says why, once
    assert len(re.findall("cannot be persisted", first.output)) == 1, first.output
    texts = [m for m in listener.messages if m.get_type() == "STATUSTEXT" and NEW_DIVE in str(m.text)]
    assert len(texts) == 1

    (store / NEXT_INDEX_FILE).rmdir()  # repaired
    start = len(listener.messages)
    second = Companion("--config", str(cfg))
    second.wait_for("companion running")
    wait_until(lambda: len(_captures(listener, start)) >= 3, 90, "the next run's captures")
    assert second.terminate() == 0, second.output
    first_seen: dict[tuple[str, int], float] = {}
    for m in _captures(listener):  # a re-sent capture (same frame, same time) is not a reuse; another frame is
        pair = _pair(m)
        assert first_seen.setdefault(pair, m.time_utc) == m.time_utc, (pair, first_seen[pair], m.time_utc)
    assert {d for d, _ in first_seen} >= {old_dive, new_dive}
