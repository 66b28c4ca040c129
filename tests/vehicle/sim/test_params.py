"""The simulator's parameters, read and changed over the wire as a ground station does (pymavlink over loopback UDP),
with ArduSub 4.7's names, types and defaults, and the failsafes and pilot response following what was set; and
MANUAL_CONTROL taken only from MAV_GCS_SYSID, aimed at this vehicle, as a GCS heartbeat too."""

from __future__ import annotations

import math
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.vehicle.sim_env import Peer, sim_and_peer
from tests.waiting import wait_until
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.params import SimParams

INT8, INT16, REAL32 = mav2.MAV_PARAM_TYPE_INT8, mav2.MAV_PARAM_TYPE_INT16, mav2.MAV_PARAM_TYPE_REAL32
NO_INDEX = 65535
"""param_index -1 (an answer to a read by name, or a set) as the uint16 field carries it."""
FIRMWARE = {  # ArduSub 4.7 (Parameters.cpp/.h, and its defaults table for PILOT_SPEED_UP)
    "FS_GCS_ENABLE": (2.0, INT8), "FS_GCS_TIMEOUT": (5.0, REAL32), "FS_PILOT_INPUT": (2.0, INT8),
    "FS_PILOT_TIMEOUT": (3.0, REAL32), "MAV_GCS_SYSID": (255.0, INT16), "PILOT_SPEED_DN": (0.0, INT16),
    "PILOT_SPEED_UP": (100.0, INT16),
}


def _dive():
    return compile_profile({"origin": None, "legs": [{"descend": {"to_m": 5.0, "rate_mps": 10.0}},
                                                      {"hold": {"s": 60.0, "mode": "ALT_HOLD"}}]})


def _values(peer: Peer, name: str) -> list[mav2.MAVLink_message]:
    return [m for m in peer.of_type("PARAM_VALUE") if m.param_id == name]


def _read(peer: Peer, name: str, index: int = -1) -> None:
    peer.send(mav2.MAVLink_param_request_read_message(1, 1, name.encode(), index))


def _set(peer: Peer, name: str, value: float, target: tuple[int, int] = (1, 1)) -> None:
    peer.send(mav2.MAVLink_param_set_message(*target, name.encode(), value, FIRMWARE[name][1]))


def test_the_parameter_list_has_the_firmware_names_types_and_defaults():
    with sim_and_peer(profile=_dive()) as (sim, peer):
        peer.send(mav2.MAVLink_param_request_list_message(1, 0))  # to any component of system 1, as QGC asks
        assert wait_until(lambda: len(peer.of_type("PARAM_VALUE")) >= len(FIRMWARE), 5)
        values = peer.of_type("PARAM_VALUE")
        assert {m.param_id: (m.param_value, m.param_type) for m in values} == FIRMWARE
        assert sorted(m.param_index for m in values) == list(range(len(FIRMWARE)))
        assert {m.param_count for m in values} == {len(FIRMWARE)}
        assert {(m.get_srcSystem(), m.get_srcComponent()) for m in values} == {(1, 1)}
        banner = [m.text for m in peer.of_type("STATUSTEXT")]
        assert banner[0].startswith("ArduSub V4.7") and "Frame: VECTORED" in banner


def test_reads_by_name_and_index_and_silence_for_unknown_ones():
    with sim_and_peer(profile=_dive()) as (sim, peer):
        _read(peer, "NO_SUCH_PARAM")
        peer.send(mav2.MAVLink_param_request_read_message(1, 1, b"", 99))  # no index 99
        _read(peer, "FS_GCS_TIMEOUT")  # asked after the two above: by its answer they would have had theirs
        assert wait_until(lambda: _values(peer, "FS_GCS_TIMEOUT"), 5)
        assert [(m.param_id, m.param_index) for m in peer.of_type("PARAM_VALUE")] == [("FS_GCS_TIMEOUT", NO_INDEX)]
        _read(peer, "", 3)
        assert wait_until(lambda: len(peer.of_type("PARAM_VALUE")) == 2, 5)
        by_index = peer.of_type("PARAM_VALUE")[-1]
        assert (by_index.param_id, by_index.param_index, by_index.param_value) == ("FS_PILOT_TIMEOUT", 3, 3.0)


def test_param_set_is_echoed_coerced_to_its_type_and_ignored_when_unknown_nan_or_for_another_component():
    with sim_and_peer(profile=_dive()) as (sim, peer):
        _set(peer, "PILOT_SPEED_DN", 30.0, target=(1, 100))  # the camera's: not the autopilot's business
        peer.send(mav2.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, REAL32))
        _set(peer, "FS_GCS_TIMEOUT", math.nan)
        _set(peer, "FS_GCS_ENABLE", 3.7)  # INT8: truncated, as AP_Param::set_float does
        assert wait_until(lambda: _values(peer, "FS_GCS_ENABLE"), 5)
        assert [(m.param_id, m.param_value, m.param_index) for m in peer.of_type("PARAM_VALUE")] == [
            ("FS_GCS_ENABLE", 3.0, NO_INDEX)]
        assert sim.params.sets == [("FS_GCS_ENABLE", 3.0)]
        assert sim.params.value("FS_GCS_TIMEOUT") == 5.0 and sim.params.value("PILOT_SPEED_DN") == 0.0
        _set(peer, "MAV_GCS_SYSID", 70000.0)  # INT16: clamped
        assert wait_until(lambda: _values(peer, "MAV_GCS_SYSID"), 5)
        assert _values(peer, "MAV_GCS_SYSID")[-1].param_value == 32767.0


def test_coercion_matches_ap_param_set_float():
    params = SimParams()
    assert [params.set("FS_PILOT_INPUT", v) for v in (1.999, -1.999, 200.0, -200.0)] == [2.0, -2.0, 127.0, -128.0]
    assert params.set("FS_PILOT_TIMEOUT", 0.25) == 0.25 and params.set("FS_PILOT_TIMEOUT", math.inf) is None
    assert params.set("NOT_A_PARAM", 1.0) is None
    with pytest.raises(ValueError, match="FS_GCS_TIMEOUT"):
        SimParams({"FS_GCS_TIMEOUT": math.nan})


def test_failsafes_and_pilot_speed_follow_the_parameters_set_over_the_wire():
    with sim_and_peer(profile=_dive()) as (sim, peer):
        for name, value in (("FS_GCS_TIMEOUT", 0.6), ("FS_GCS_ENABLE", 4.0), ("PILOT_SPEED_DN", 30.0)):
            _set(peer, name, value)
        assert wait_until(lambda: len(peer.of_type("PARAM_VALUE")) == 3, 5)
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0))  # full down: PILOT_SPEED_DN
        assert wait_until(lambda: sim.state().vd == pytest.approx(0.3), 3)
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))
        peer.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        # the GCS lost after 0.6 s: with FS_GCS_ENABLE 4 the vehicle surfaces at PILOT_SPEED_UP (the pilot-input
        # failsafe, 3 s, comes later)
        assert wait_until(lambda: [kind for _t, kind in sim.failsafes] == ["gcs"], 3)
        assert sim.state().mode == "SURFACE" and sim.state().vd == pytest.approx(-1.0)
        # the record is made before the warning is sent: the warning is still on its way over UDP
        assert wait_until(lambda: any(m.text == "MYGCS: 255, heartbeat lost" for m in peer.of_type("STATUSTEXT")), 2)


def test_manual_control_counts_only_from_the_ground_station_and_aimed_at_this_vehicle():
    with sim_and_peer(profile=_dive(), pilot_timeout_s=0.4, gcs_timeout_s=0.4) as (sim, peer):
        assert wait_until(lambda: sim.state().vd == 0.0, 3)  # the scripted descent is over: holding at 5 m
        peer.conn.mav.srcSystem = 1  # a companion computer of the vehicle
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0))
        peer.conn.mav.srcSystem = 255  # the ground station
        peer.send(mav2.MAVLink_manual_control_message(0, 0, 0, 0, 0, 0))  # broadcast target: not "aimed at us"
        peer.send(mav2.MAVLink_manual_control_message(2, 0, 0, 0, 0, 0))  # another vehicle's
        _read(peer, "FS_PILOT_INPUT")
        assert wait_until(lambda: peer.of_type("PARAM_VALUE"), 5)  # everything above was handled by now
        assert sim.manual_control_senders == {(1, 190), (255, 190)}
        assert sim.state().vd == 0.0
        time.sleep(0.6)  # past both timeouts: none of those inputs started either failsafe
        assert sim.failsafes == [] and sim.state().armed
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0))
        assert wait_until(lambda: sim.state().vd == pytest.approx(1.0), 3)
        assert wait_until(lambda: sorted(kind for _t, kind in sim.failsafes) == ["gcs", "pilot_input"], 3)
