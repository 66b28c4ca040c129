"""Status lines and 1 Hz values: lengths, names, severities, and their arrival over UDP."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import SurfaceConfig
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link, ground_station, wait_for
from vehicle.camera import status as st
from vehicle.camera.downlink import Downlink


def test_lines_and_names_follow_the_rules():
    long = st.status_text("x" * 80 + "é", st.INFO)
    assert len(long.text) == 50
    assert st.link_text(False)[1] == mav.MAV_SEVERITY_WARNING and st.link_text(True)[1] == mav.MAV_SEVERITY_INFO
    assert st.camera_text(False)[1] == mav.MAV_SEVERITY_WARNING
    assert [st.link_text(True, first=True)[0], st.link_text(False)[0], st.link_text(True)[0]] == [
        "Autopilot link up", "Autopilot link lost", "Autopilot link back"]
    assert all(len(n) <= 10 and n not in st.RESERVED_NAMES for n in st.VALUE_NAMES)
    with pytest.raises(ValueError):
        st.named_value("CamTilt", 1.0, 0)
    with pytest.raises(ValueError):
        st.status_text("x", 9)
    rep = st.StatusReporter(lambda: 5)
    rep.update(fps=4.8, seen_fps=10.0, depth_m=None)
    values = {m.name: m.value for m in rep.messages()}
    assert values["MRL_FPS"] == pytest.approx(4.8) and math.isnan(values["MRL_DEPTH"])
    assert values["MRL_SEEN"] == pytest.approx(10.0)  # the camera's rate beside the scored one
    with pytest.raises(TypeError):
        rep.update(nonsense=1)


def test_values_and_events_arrive_over_udp():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, status_hz=5), version="0.1.0")
    gcs = ground_station(port)
    wait_for(gcs, "HEARTBEAT")
    surface.start()
    try:
        started = wait_for(gcs, "STATUSTEXT")
        assert started.text == "MERLION 0.1.0 started" and started.severity == mav.MAV_SEVERITY_INFO
        surface.update_status(fps=5.0, score=0.73, summary=4, depth_m=8.25)
        surface.event(*st.camera_text(False))
        lost = wait_for(gcs, "STATUSTEXT", cond=lambda m: "Camera" in m.text)
        assert lost.severity == mav.MAV_SEVERITY_WARNING
        got = {}
        while len(got) < 5:
            msg = wait_for(gcs, "NAMED_VALUE_FLOAT", cond=lambda m: m.name == "MRL_DEPTH" and m.value == 8.25
                           or m.name != "MRL_DEPTH")
            assert msg is not None
            got[msg.name] = msg.value
        assert got["MRL_SCORE"] == pytest.approx(0.73) and got["MRL_SUMN"] == 4
        link_bps = wait_for(gcs, "NAMED_VALUE_FLOAT", cond=lambda m: m.name == "MRL_LINKBS" and m.value > 0)
        assert link_bps is not None
    finally:
        gcs.close()
        surface.stop()
        link.stop()
