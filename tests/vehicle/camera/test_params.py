"""Live tuning over the MAVLink parameter protocol: list, read, set, echo, persistence across a restart."""

from __future__ import annotations

import json
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import Config, SurfaceConfig
from companion.live.control.params import SERVED, default_params
from companion.storage.params_file import FILE_VERSION, ParamsFile
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link, ground_station, wait_for
from vehicle.camera.downlink import Downlink
from vehicle.camera.params import ParamServer, ParamSpec


def _values(gcs, n: int) -> dict[str, object]:
    out = {}
    while len(out) < n:
        msg = wait_for(gcs, "PARAM_VALUE")
        assert msg is not None, f"only {len(out)} of {n} PARAM_VALUE arrived"
        out[msg.param_id] = msg
    return out


def test_list_read_set_and_restart(tmp_path):
    path = tmp_path / "params.json"
    cfg = Config()
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000), params=default_params(cfg),
                          saved_params=ParamsFile(path).load(),
                       persist_params=ParamsFile(path).save)
    seen = []
    surface.on_param_changed(lambda name, value: seen.append((name, value)))
    surface.start()
    gcs = ground_station(port)
    try:
        gcs.mav.param_request_list_send(1, 100)
        listed = _values(gcs, len(SERVED))
        assert set(listed) == set(SERVED) >= {"MERL_TAU_SS", "MERL_TAU_SES", "MERL_K", "MERL_THUMB_B",
                                              "MERL_LINK_BPS", "MERL_GATE", "MERL_ENHANCE"}
        assert all(len(name) <= 16 and m.param_count == len(SERVED) for name, m in listed.items())
        assert [listed[name].param_index for name in SERVED] == list(range(len(SERVED)))  # the wire order
        assert listed["MERL_GATE"].param_value == pytest.approx(cfg.gate.threshold)
        assert listed["MERL_K"].param_value == 6 and listed["MERL_K"].param_type == mav.MAV_PARAM_TYPE_INT32
        assert listed["MERL_TAU_SS"].param_value == pytest.approx(0.5)

        gcs.mav.param_set_send(1, 100, b"MERL_TAU_SS", 0.42, mav.MAV_PARAM_TYPE_REAL32)
        echo = wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_TAU_SS")
        assert echo.param_value == pytest.approx(0.42)
        assert seen == [("MERL_TAU_SS", pytest.approx(0.42))]
        gcs.mav.param_set_send(1, 100, b"MERL_LINK_BPS", 3000, mav.MAV_PARAM_TYPE_INT32)
        assert wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_LINK_BPS").param_value == 3000
        assert surface.budget.rate == 3000  # took effect at once
        gcs.mav.param_set_send(1, 100, b"MERL_K", 2.5, mav.MAV_PARAM_TYPE_INT32)  # not a whole number
        assert wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_K").param_value == 6
        gcs.mav.param_set_send(1, 101, b"MERL_K", 9, mav.MAV_PARAM_TYPE_INT32)  # another component's
        gcs.mav.param_request_read_send(1, 100, b"", 2)  # by index
        assert wait_for(gcs, "PARAM_VALUE").param_id == "MERL_K"
        gcs.mav.param_request_read_send(1, 100, b"MERL_ENHANCE", -1)  # by name
        assert wait_for(gcs, "PARAM_VALUE").param_id == "MERL_ENHANCE"
        assert surface.params.value("MERL_K") == 6
    finally:
        gcs.close()
        surface.stop()
        link.stop()

    saved = json.loads(path.read_text())
    assert saved["params"]["MERL_TAU_SS"] == pytest.approx(0.42) and saved["version"] == FILE_VERSION
    assert not [p for p in tmp_path.iterdir() if p.name != "params.json"]  # no temp files left behind
    link2 = companion_link(free_udp_port())
    again = Downlink(link2, SurfaceConfig(), params=default_params(cfg), saved_params=ParamsFile(path).load(),
                       persist_params=ParamsFile(path).save)
    replayed = []
    again.on_param_changed(lambda name, value: replayed.append((name, value)))
    assert again.params.value("MERL_TAU_SS") == pytest.approx(0.42)
    assert again.budget.rate == 3000
    assert dict(replayed) == {"MERL_TAU_SS": pytest.approx(0.42), "MERL_LINK_BPS": 3000}
    link2.stop()


def test_the_downlink_alone_serves_and_applies_its_own_link_parameters(tmp_path):
    """Without the companion (no app parameters at all): MERL_THUMB_B and MERL_LINK_BPS are listed, set, echoed,
    refused out of range, saved, and in force again after a restart."""
    path = tmp_path / "params.json"
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, thumbnail_bytes=2500),
                       saved_params=ParamsFile(path).load(), persist_params=ParamsFile(path).save)
    surface.start()
    gcs = ground_station(port)
    try:
        gcs.mav.param_request_list_send(1, 100)
        listed = _values(gcs, 2)
        assert {name: m.param_value for name, m in listed.items()} == {"MERL_THUMB_B": 2500, "MERL_LINK_BPS": 20000}
        assert all(m.param_count == 2 and m.param_type == mav.MAV_PARAM_TYPE_INT32 for m in listed.values())
        gcs.mav.param_set_send(1, 100, b"MERL_LINK_BPS", 3000, mav.MAV_PARAM_TYPE_INT32)
        assert wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_LINK_BPS").param_value == 3000
        assert surface.budget.rate == 3000
        gcs.mav.param_set_send(1, 100, b"MERL_THUMB_B", 4000, mav.MAV_PARAM_TYPE_INT32)
        assert wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_THUMB_B").param_value == 4000
        assert surface.thumbnail_bytes == 4000
        gcs.mav.param_set_send(1, 100, b"MERL_THUMB_B", 100, mav.MAV_PARAM_TYPE_INT32)  # below 300: refused
        assert wait_for(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "MERL_THUMB_B").param_value == 4000
        assert surface.thumbnail_bytes == 4000
    finally:
        gcs.close()
        surface.stop()
        link.stop()
    assert json.loads(path.read_text())["params"] == {"MERL_THUMB_B": 4000, "MERL_LINK_BPS": 3000}
    link2 = companion_link(free_udp_port())
    again = Downlink(link2, SurfaceConfig(budget_bytes_per_s=20000, thumbnail_bytes=2500),
                     saved_params=ParamsFile(path).load(), persist_params=ParamsFile(path).save)
    assert again.budget.rate == 3000 and again.thumbnail_bytes == 4000
    assert again.params.values() == {"MERL_THUMB_B": 4000, "MERL_LINK_BPS": 3000}
    link2.stop()


def test_refusals_and_bad_saved_values():
    saved: list[dict] = []
    server = ParamServer([ParamSpec("MERL_K", 6, 1, 10, integer=True)], system_id=lambda: 1, component_id=100,
                         saved={"MERL_K": "junk", "MERL_GONE": 3}, persist=saved.append)
    assert server.value("MERL_K") == 6 and server.restored == {}  # bad saved values are ignored, never fatal

    def veto(name, value):
        if value == 7:
            raise ValueError("seven is unlucky")

    server.on_change(veto)
    assert not server.set("MERL_K", 7) and server.value("MERL_K") == 6
    assert not server.set("MERL_K", float("nan")) and not server.set("MERL_K", 11)
    assert server.set("MERL_K", 8) and saved == [{"MERL_K": 8}]
    with pytest.raises(ValueError, match="longer than 16"):
        ParamServer([ParamSpec("MERL_THIS_IS_TOO_LONG", 1, 0, 2)], system_id=lambda: 1, component_id=100)


def test_a_callback_runs_outside_the_servers_lock():
    """A callback that waits on another thread which saves a parameter (as the companion's waits on its summary
    keeper) must not hold the server's lock: the other save finishes while the callback waits."""
    saved: list[dict] = []
    server = ParamServer([ParamSpec("MERL_K", 6, 1, 10, integer=True), ParamSpec("MERL_GATE", 8.0, 0.0, 255.0)],
                         system_id=lambda: 1, component_id=100, persist=saved.append)
    other_done = threading.Event()

    def waits_on_another_thread(name, value):
        if name == "MERL_K":
            other = threading.Thread(target=lambda: server.set("MERL_GATE", 4.0) and other_done.set())
            other.start()
            other.join(10)

    server.on_change(waits_on_another_thread)
    assert server.set("MERL_K", 7)
    assert other_done.is_set(), "the other save waited for the callback: it ran under the server's lock"
    assert server.values() == {"MERL_K": 7, "MERL_GATE": 4.0} and saved[-1] == {"MERL_K": 7, "MERL_GATE": 4.0}
