"""The simulated ArduSub's failsafes (``vehicle/sim/failsafes.py``) as the firmware's ``failsafe.cpp`` runs them:
the pilot-input failsafe and the GCS failsafe, seen from a ground station on loopback UDP (pymavlink)."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.vehicle.sim_env import sim_and_peer
from tests.waiting import wait_until
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import FS_GCS_TIMEOUT_S, FS_PILOT_TIMEOUT_S


def _profile(origin: dict | None = None, armed: bool = True):
    return compile_profile({"origin": origin, "armed": armed, "legs": [{"hold": {"s": 2.0, "mode": "ALT_HOLD"}},
                                                                        {"descend": {"to_m": 20, "rate_mps": 0.5}}]})


def test_pilot_input_failsafe_disarms_when_manual_control_stops_and_reports_it():
    assert FS_PILOT_TIMEOUT_S == 3.0  # the firmware default; the test uses a shorter one to stay quick
    with sim_and_peer(profile=_profile(None), pilot_timeout_s=0.8) as (sim, peer):
        time.sleep(1.0)
        assert sim.failsafes == [], "armed without a joystick ever connected: no pilot-input failsafe"
        for _ in range(5):
            peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))
            time.sleep(0.1)
        assert sim.state().armed
        assert wait_until(lambda: [kind for _t, kind in sim.failsafes] == ["pilot_input"], 3)
        assert wait_until(lambda: any(m.text == "Lost manual control" and m.severity == mav2.MAV_SEVERITY_CRITICAL
                                      for m in peer.of_type("STATUSTEXT")), 2)
        since = time.monotonic()
        assert wait_until(lambda: peer.of_type("HEARTBEAT", since), 3)
        after = peer.of_type("HEARTBEAT", since)[-1]
        assert not after.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED
        assert after.system_status == mav2.MAV_STATE_CRITICAL  # a failsafe is on until the pilot is back
        assert sim.manual_control_senders == {(255, 190)}
        held = sim.state().depth  # disarmed: the scripted descent no longer moves it
        time.sleep(0.3)
        assert sim.state().depth == held and sim.state().vd == 0.0


def test_gcs_failsafe_after_system_255_heartbeats_stop():
    assert FS_GCS_TIMEOUT_S == 5.0
    with sim_and_peer(profile=_profile(None), gcs_timeout_s=0.8, gcs_failsafe="depth_hold") as (sim, peer):
        time.sleep(1.0)
        assert sim.failsafes == [], "no GCS seen yet: no GCS failsafe"
        for _ in range(3):
            peer.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
            time.sleep(0.2)
        assert wait_until(lambda: (255, 190, mav2.MAV_TYPE_GCS) in sim.heartbeat_senders, 2) and sim.failsafes == []
        assert wait_until(lambda: [kind for _t, kind in sim.failsafes] == ["gcs"], 3)
        assert wait_until(lambda: any(m.text == "MYGCS: 255, heartbeat lost" for m in peer.of_type("STATUSTEXT")), 2)
        assert sim.state().mode == "ALT_HOLD"  # FS_GCS_ENABLE 3 = depth hold: it stops descending
        held = sim.state().depth
        time.sleep(0.3)
        assert sim.state().depth == held > 0 and sim.state().armed
    # the firmware's default action (FS_GCS_ENABLE 2) disarms
    with sim_and_peer(profile=_profile(None), gcs_timeout_s=0.5) as (sim, peer):
        peer.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        assert wait_until(lambda: [kind for _t, kind in sim.failsafes] == ["gcs"], 3)
        assert not sim.state().armed
        # heartbeats from another system (a companion computer) never arm it
    with sim_and_peer(system=1, profile=_profile(None), gcs_timeout_s=0.5) as (sim, peer):
        peer.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_ONBOARD_CONTROLLER, mav2.MAV_AUTOPILOT_INVALID,
                                                 0, 0, 0, 3))
        assert wait_until(lambda: (1, 190, mav2.MAV_TYPE_ONBOARD_CONTROLLER) in sim.heartbeat_senders, 2)
        time.sleep(1.2)  # from when it was heard, past the 0.5 s timeout
        assert sim.failsafes == []
