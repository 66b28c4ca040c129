"""The live companion with its store on a real tiny tmpfs: the disk fills up (the surface hears one WARNING), the
run is killed while it is full (no image index announced comes again), the next run is told when space returns
(it writes what it kept in memory), and a PARAM_SET on a read-only store is still answered."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymavlink import mavutil

from companion.config import StoreConfig
from companion.storage.store import Store
from tests.companion.conftest import fill_disk, tiny_tmpfs
from tests.companion.live_harness import Companion, wait_until, write_config

FULL = "Store disk full"
BACK = "Store writable again"


def _captures(listener, start: int = 0) -> list[int]:
    return [m.image_index for m in listener.messages[start:]
            if m.get_type() == "CAMERA_IMAGE_CAPTURED" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)]


def _texts(listener, needle: str, start: int = 0) -> list:
    return [m for m in listener.messages[start:] if m.get_type() == "STATUSTEXT" and needle in str(m.text)]


@pytest.mark.slow
def test_a_full_store_is_reported_once_recovered_and_no_index_comes_twice(tmp_path: Path, dive) -> None:
    hub, _gcs, listener = dive
    with tiny_tmpfs(tmp_path / "mnt", "size=4m") as mnt:
        store = mnt / "store"
        cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                           sampler={"k": 4}, source={"uri": "synthetic://dive?seconds=2&width=320&height=240"})
        first = Companion("--config", str(cfg))
        first.wait_for("companion running")
        wait_until(lambda: len(_captures(listener)) >= 2, 60, "captures on disk")
        fill_disk(mnt / "filler")
        warned = listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and FULL in str(m.text), 60, FULL)
        assert warned.severity == 4  # MAV_SEVERITY_WARNING
        mark = len(listener.messages)
        wait_until(lambda: len(set(_captures(listener, mark))) >= 3, 90, "captures announced while full")
        first.kill()  # ends while the disk is full: what it announced is in memory only
        announced = _captures(listener)
        assert len(_texts(listener, FULL)) == 1, "said once, however many writes failed"
        resumed = Store(StoreConfig(dir=str(store)))
        assert resumed.next_image_index > max(announced), (resumed.next_image_index, max(announced))

        start = len(listener.messages)
        second = Companion("--config", str(cfg))  # the disk is still full
        second.wait_for("companion running")
        listener.wait_for(lambda m: m in listener.messages[start:] and m.get_type() == "STATUSTEXT"
                          and FULL in str(m.text), 60, "the second run's warning")
        (mnt / "filler").unlink()
        listener.wait_for(lambda m: m in listener.messages[start:] and m.get_type() == "STATUSTEXT"
                          and BACK in str(m.text), 60, BACK)
        wait_until(lambda: [i for i in _captures(listener, start) if i not in resumed.summary], 60, "new captures")
        new = [i for i in _captures(listener, start) if i not in resumed.summary]
        assert min(new) > max(announced), (new, announced)  # never an index of the killed run again
        assert second.terminate() == 0, second.output
        final = second.wait_for("merlion run: seen")
        assert "on disk" in final and "memory-only" not in final
        again = Store(StoreConfig(dir=str(store)))
        assert again.dive == resumed.dive and again.summary
        for i in again.summary:
            assert (store / "frames" / f"{i:06d}.jpg").is_file()


def _answered(listener, start: int) -> bool:
    return any(m.get_type() == "PARAM_VALUE" and m.param_id == "MERL_K" for m in listener.messages[start:])


def test_a_param_set_on_a_read_only_store_is_still_answered(tmp_path: Path, dive) -> None:
    hub, gcs, listener = dive
    with tiny_tmpfs(tmp_path / "ro", "size=1m,ro") as mnt:
        cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(mnt / "store")})
        companion = Companion("--config", str(cfg))
        companion.wait_for("companion running")
        listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "Store read-only" in str(m.text), 60,
                          "the read-only warning")
        wait_until(lambda: (gcs.mav.param_request_read_send(1, 100, b"MERL_K", -1), _answered(listener, 0))[1], 30,
                   "the companion answering reads")
        start = len(listener.messages)
        gcs.mav.param_set_send(1, 100, b"MERL_K", 5.0, mavutil.mavlink.MAV_PARAM_TYPE_INT32)  # once: a retry would
        listener.wait_for(lambda m: m in listener.messages[start:] and m.get_type() == "PARAM_VALUE"  # hide it
                          and m.param_id == "MERL_K" and m.param_value == 5, 10, "the PARAM_SET's PARAM_VALUE")
        assert companion.alive()
        assert companion.terminate() == 0, companion.output
