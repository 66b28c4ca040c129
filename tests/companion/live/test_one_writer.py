"""One writer (issue 12 item 1): the store on disk equals the sampler's summary after every change, whoever makes it.

A real `merlion run` with the simulated ArduSub behind a UDP hub and a ground station (pymavlink, with its
mavftp client) on the same hub: while frames flow, the ground station changes MERL_K, MERL_TAU_SS (to 0: no
gate), uploads new queries over FTP and switches enhancement off and on. After each change it reads what the
companion's summary keeper holds (/store/summary.json over FTP) and the store's files, and checks that they agree
change by change: the store's change log line n holds exactly the summary the sampler held after n events, every
frame the store's index names decodes, and nothing was ever found out of step.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from pymavlink import mavftp

from companion.atomic_write import TMP_PREFIX
from tests.companion.live_harness import (
    Companion,
    ftp_get_json,
    ground_ftp,
    set_param,
    store_summary,
    wait_until,
    write_config,
)

KEEPER = "/store/summary.json"


def check_in_step(store: Path, keeper: dict) -> None:
    """The store's change log agrees with the keeper change by change; its index names only whole frames."""
    assert keeper["mismatches"] == 0
    index = store_summary(store)  # first: the store logs a change, then rewrites the index; frames keep coming
    lines = [json.loads(line) for line in (store / "changes.jsonl").read_text().splitlines()]
    assert keeper["history"], "no change was recorded"
    for applied, summary in keeper["history"]:
        assert lines[applied - 1]["summary"] == summary, f"store and summary differ after event {applied}"
    assert index["summary"] in [line["summary"] for line in lines]
    for i in index["summary"]:
        base = store / "frames" / f"{i:06d}"
        assert cv2.imread(str(base.with_suffix(".jpg"))) is not None
        np.load(base.with_suffix(".npy"))
        assert json.loads(base.with_suffix(".json").read_text())["image_index"] == i


def test_store_equals_summary_after_every_change_from_the_surface(tmp_path: Path, dive) -> None:
    hub, gcs, listener = dive
    store = tmp_path / "store"
    cfg = write_config(
        tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)}, sampler={"k": 8},
        source={"uri": "synthetic://dive?seconds=40&width=160&height=96", "fps": 10},
        queries={"tau_ss": 0.3},
        enhance={"mode": "selective", "method": "classic", "tau_ses": 0.3},
        surface={"ftp_writable": True, "push": False, "budget_bytes_per_s": 200000},
    )
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    wait_until(lambda: len(store_summary(store).get("summary", [])) >= 3, 60, "three summary frames on disk")
    client = ground_ftp(gcs)
    local = tmp_path / "keeper.json"
    queries = tmp_path / "queries.txt"
    queries.write_text("underwater image of rocks\nunderwater image of open water\n")
    changes = [("MERL_K", 4), ("MERL_TAU_SS", 0.0), ("queries", None), ("MERL_ENHANCE", 0), ("MERL_K", 10),
               ("MERL_ENHANCE", 1), ("MERL_TAU_SS", 0.4), ("MERL_K", 3)]
    for name, value in changes:
        before = ftp_get_json(client, KEEPER, local)["applied"]
        if name == "queries":
            client.cmd_put([str(queries), "/config/queries.txt"])
            assert client.process_ftp_reply("put", timeout=15).error_code == mavftp.FtpError.Success
            companion.wait_for("queries set: 'underwater image of rocks'")
        else:
            set_param(gcs, listener, name, value, integer=name != "MERL_TAU_SS")
        if name == "MERL_K":
            wait_until(lambda v=value: len(store_summary(store).get("summary", [])) <= v, 10, f"K={value} on disk")
        # frames keep flowing: wait for at least one more event after the change, then compare
        wait_until(lambda b=before: ftp_get_json(client, KEEPER, local)["applied"] > b, 30, f"an event after {name}")
        keeper = ftp_get_json(client, KEEPER, local)
        check_in_step(store, keeper)
        if name == "MERL_K":
            assert len(keeper["summary"]) <= value
    assert companion.terminate() == 0, companion.output
    assert "MERL_ENHANCE refused" not in companion.output
    last = [json.loads(line) for line in (store / "changes.jsonl").read_text().splitlines()][-1]
    assert store_summary(store)["summary"] == last["summary"]
    assert not list(store.rglob(f"{TMP_PREFIX}*"))
