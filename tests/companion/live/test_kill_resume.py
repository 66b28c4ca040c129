"""Crash safety with one writer (issue 12 item 1): SIGKILL at 5 random moments of a dive, restart on the same store.

Each time the store must be whole (index parses, every frame it names decodes, no temporary file survives the
reopening), the restarted companion must resume exactly that summary and its next image index, and the dive
must go on from there: image indices only ever increase over all the runs, never start over.
"""

from __future__ import annotations

import contextlib
import json
import random
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.atomic_write import TMP_PREFIX
from companion.config import StoreConfig
from companion.storage.store import Store
from tests.companion.live_harness import Companion, store_summary, wait_until, write_config


def check_whole(store: Path) -> Store:
    """Reopen the store as a restart would; it must be consistent on disk."""
    reopened = Store(StoreConfig(dir=str(store)))
    assert not list(store.rglob(f"{TMP_PREFIX}*")), "temporary files survived the reopening"
    index = store_summary(store)
    if (store / "summary.json").exists():
        assert isinstance(index.get("summary"), list), "summary.json does not parse"
        assert reopened.summary == index["summary"], "a frame the index names is not whole on disk"
    for i in reopened.summary:
        base = store / "frames" / f"{i:06d}"
        assert cv2.imread(str(base.with_suffix(".jpg"))) is not None, f"frame {i} does not decode"
        np.load(base.with_suffix(".npy"))
        assert json.loads(base.with_suffix(".json").read_text())["image_index"] == i
    return reopened


def _added(store: Path) -> list[int]:
    out = []
    path = store / "changes.jsonl"
    for line in path.read_text().splitlines() if path.exists() else []:
        with contextlib.suppress(ValueError):  # the last line may be cut short by the kill
            entry = json.loads(line)
            if entry["kind"] == "added":
                out.append(entry["image_index"])
    return out


@pytest.mark.slow
def test_sigkill_at_five_random_moments_then_the_dive_goes_on(tmp_path: Path) -> None:
    store = tmp_path / "store"
    # no semantic gate (tau_ss 0) and room in the summary (k 40): every frame that is not a near-duplicate enters
    # it, so each run stores a frame within a second or two whatever the kill moments were (with k 6 and the gate a
    # restart could wait over a minute for a frame both past the gate and farther from the kept ones than they are
    # from each other); what is tested is the store across kills, not the sampler's choice (test_summary_keeper)
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": None}, store={"dir": str(store)},
                       sampler={"k": 40}, source={"fps": 20, "realtime": True}, queries={"tau_ss": 0})

    def start(run: int) -> Companion:
        # each run films a fresh stretch of the dive (another seed), as a camera does after a restart: a replay
        # of the first run's footage would be near what the summary holds, and be a while adding anything new
        dive = f"synthetic://dive?seconds=60&width=160&height=96&seed={run + 1}"
        return Companion("--config", str(cfg), "--source", dive)
    seed = random.randrange(1 << 30)
    rng = random.Random(seed)
    held: list[int] = []
    next_index = 0
    for kill in range(5):
        companion = start(kill)
        if held:
            line = companion.wait_for("resuming with")
            assert f"resuming with {len(held)} summary frame(s); next image index {next_index}" in line, \
                (seed, line)
        else:
            companion.wait_for("companion running")
        before = len(_added(store))
        wait_until(lambda b=before: len(_added(store)) > b, 60, f"a new frame stored (seed {seed}, run {kill})")
        with contextlib.suppress(subprocess.TimeoutExpired):  # then a random moment of the run
            companion.proc.wait(rng.uniform(0.0, 1.5))
        companion.kill()
        reopened = check_whole(store)
        assert reopened.next_image_index >= next_index, f"seed {seed}: image indices went back after kill {kill}"
        held, next_index = reopened.summary, reopened.next_image_index

    last = start(5)
    last.wait_for(f"resuming with {len(held)} summary frame")
    log_before = len((store / "changes.jsonl").read_text().splitlines())
    before = len(_added(store))
    wait_until(lambda: len(_added(store)) > before, 60, f"a frame after the last restart (seed {seed})")
    assert last.terminate() == 0, last.output
    check_whole(store)
    added = _added(store)
    assert added == sorted(set(added)), f"seed {seed}: an image index was reused: {added}"
    assert added[-1] >= next_index, "the dive started over instead of going on"
    entries = [json.loads(line) for line in (store / "changes.jsonl").read_text().splitlines()[log_before:]]
    trimmed = {e["image_index"] for e in entries if e["kind"] == "removed"}
    final = store_summary(store)["summary"]
    assert set(held) - set(final) <= trimmed, "resumed frames were lost other than by the sampler's choice"
    assert [i for i in final if i in held] == [i for i in held if i not in trimmed]
