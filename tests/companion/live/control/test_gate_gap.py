"""MERL_GATE_GAP end to end over real UDP: a ground station sets it, the pipeline's frame gate takes it (through
the summary keeper's queue), a value out of range is refused, and the value survives a restart."""

from __future__ import annotations

import json
from pathlib import Path

from companion.config import build_config
from companion.live.companion import LiveCompanion
from companion.live.control.params import TUNABLES
from tests.companion.live_harness import set_param


def _config(store: Path, hub_url: str):
    return build_config({
        "source": {"uri": "synthetic://dive?seconds=2&width=160&height=96", "fps": 10, "realtime": True,
                   "loop": True},
        "encoder": {"name": "visual"}, "gate": {"mode": "difference", "max_gap_s": 1.0},
        "mavlink": {"connection": hub_url}, "store": {"dir": str(store)},
    })


def test_merl_gate_gap_from_a_ground_station_is_applied_saved_and_kept_across_a_restart(tmp_path: Path,
                                                                                        dive) -> None:
    hub, gcs, listener = dive
    store = tmp_path / "store"
    row = next(t for t in TUNABLES if t.name == "MERL_GATE_GAP")
    assert row.applied_by == "summary"  # a pipeline setting: the keeper's thread applies it between batches
    app = LiveCompanion(_config(store, hub.url))
    app.start()
    try:
        assert app.pipeline.gate.max_gap_s == 1.0
        echo = set_param(gcs, listener, "MERL_GATE_GAP", 5.0, integer=False)
        assert echo.param_value == 5.0
        assert app.pipeline.gate.max_gap_s == 5.0  # in force when the echo left
        set_param(gcs, listener, "MERL_GATE_GAP", 0.0, integer=False, expect=5.0)  # below 0.1: refused
        assert app.pipeline.gate.max_gap_s == 5.0
        assert json.loads((store / "params.json").read_text())["params"]["MERL_GATE_GAP"] == 5.0
    finally:
        app.stop()

    again = LiveCompanion(_config(store, hub.url))
    again.start()
    try:
        assert again.pipeline.gate.max_gap_s == 5.0
        start = len(listener.messages)
        gcs.mav.param_request_read_send(1, 100, b"MERL_GATE_GAP", -1)
        read = listener.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MERL_GATE_GAP"
                                 and m in listener.messages[start:], 10, "MERL_GATE_GAP read")
        assert read.param_value == 5.0
    finally:
        again.stop()
