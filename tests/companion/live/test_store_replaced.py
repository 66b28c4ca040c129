"""The store folder replaced under a running companion (renamed away, a new one made at the same path): the lock
of the old folder no longer guards the path, so a second `merlion run` takes the new folder. The first run must
notice (its lock file is no longer the path's) and write nothing more at the path: before, it went on writing
into the second run's store (its next_index at once, its frames and summary.json as soon as the new folder had a
frames/ folder), so two processes wrote one store."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from tests.companion.live_harness import Companion, store_summary, wait_until, write_config


def _lines(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()] if path.exists() else []


@pytest.mark.slow
def test_a_run_whose_store_folder_is_replaced_stops_writing_there(tmp_path: Path) -> None:
    store = tmp_path / "store"
    common = {"mavlink": {"connection": None}, "queries": {"tau_ss": 0}, "sampler": {"k": 4},
              "source": {"uri": "synthetic://dive?seconds=60&width=160&height=96"}}
    first = Companion("--config", str(write_config(tmp_path / "a.yaml", store={"dir": str(store)}, **common)))
    first.wait_for("companion running")
    wait_until(lambda: store_summary(store).get("summary"), 60, "a frame stored by the first run")
    first_dive = store_summary(store)["dive"]

    old = tmp_path / "store.old"
    store.rename(old)
    store.mkdir()
    mark = first.mark()
    line = first.wait_for(r"store .* replaced", 30, start=mark)
    assert f"store {store}:" in line and "writes nothing more there" in line, line
    assert sorted(p.name for p in store.iterdir()) == [], "the first run wrote into the new folder"

    second = Companion("--config", str(write_config(tmp_path / "b.yaml", store={"dir": str(store)}, **common)))
    second.wait_for("companion running")
    second_dive = store_summary(store)["dive"]
    assert second_dive and second_dive != first_dive
    time.sleep(7)  # past the memory-only store's 5 s retry: the first run must not come back on disk here
    assert first.alive() and second.alive()
    assert second.terminate() == 0, second.output
    assert first.terminate() == 0, first.output
    assert "writable again" not in first.output[len("\n".join(first.lines[:mark])):]

    doc = store_summary(store)
    assert doc["dive"] == second_dive
    assert all(e.get("kind") != "back_on_disk" for e in _lines(store / "changes.jsonl"))
    for index in doc["summary"]:
        assert (store / "frames" / f"{index:06d}.json").is_file()
    kept = store_summary(old)  # what the first run saved before the swap: intact where it was moved
    assert kept["dive"] == first_dive
    for index in kept["summary"]:
        assert json.loads((old / "frames" / f"{index:06d}.json").read_text())["image_index"] == index
