"""The simulated ArduSub's messages read back through the companion's own depth and pose conversions."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.autopilot.telemetry import depth_from_pressure
from vehicle.sim.dive_profile import Origin, VehicleState
from vehicle.sim.messages import Moment, build_message

STATE = VehicleState(t=5.0, north=3.0, east=-4.0, depth=12.5, vn=0.3, ve=-0.4, vd=0.1, roll=0.05, pitch=-0.1,
                     yaw=math.radians(350.0), mode="ALT_HOLD", armed=True, lat=None, lon=None, alt_m=None)


def _at(origin: Origin | None) -> Moment:
    return Moment(boot_ms=5000, wall_s=1.7e9, since_start_s=600.0, origin=origin, surface_pressure_hpa=1013.25,
                  fluid_density=1025.0)


def _wire(msg: mav2.MAVLink_message) -> mav2.MAVLink_message:
    (back,) = mav2.MAVLink(None, srcSystem=1, srcComponent=1).parse_buffer(
        msg.pack(mav2.MAVLink(None, srcSystem=1, srcComponent=1)))
    return back


def test_depth_pressure_and_position_mean_what_the_companion_reads_from_them():
    without = _at(None)
    press = _wire(build_message("SCALED_PRESSURE2", STATE, without))
    assert depth_from_pressure(press.press_abs, 1025.0, 1013.25) == pytest.approx(12.5, abs=1e-3)
    gpi = _wire(build_message("GLOBAL_POSITION_INT", STATE, without))
    assert (gpi.lat, gpi.lon, gpi.alt) == (0, 0, 0) and gpi.relative_alt == -12500 and gpi.hdg == 35000
    assert _wire(build_message("VFR_HUD", STATE, without)).alt == 0.0  # no EKF origin: ArduSub sends 0
    with_origin = _wire(build_message("GLOBAL_POSITION_INT", STATE, _at(Origin(-33.8, 151.3, 0.0))))
    assert with_origin.lat == pytest.approx(-33.8e7 + 3.0 / 111_000 * 1e7, abs=20)
    assert with_origin.alt == -12500
    attitude = _wire(build_message("ATTITUDE", STATE, without))
    assert attitude.yaw == pytest.approx(math.radians(-10.0), abs=1e-6) and attitude.time_boot_ms == 5000
    heartbeat = _wire(build_message("HEARTBEAT", STATE, without))
    assert heartbeat.custom_mode == 2 and heartbeat.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED


def test_the_heartbeat_says_what_ardusub_says_of_its_mode_arming_and_failsafes():
    flags = {name: getattr(mav2, f"MAV_MODE_FLAG_{name}") for name in
             ("CUSTOM_MODE_ENABLED", "STABILIZE_ENABLED", "MANUAL_INPUT_ENABLED", "GUIDED_ENABLED", "SAFETY_ARMED")}

    def heartbeat(state: VehicleState, failsafe: bool = False) -> tuple[set[str], int]:
        at = Moment(boot_ms=1, wall_s=1.7e9, since_start_s=1.0, origin=None, surface_pressure_hpa=1013.25,
                    fluid_density=1025.0, failsafe=failsafe)
        hb = _wire(build_message("HEARTBEAT", state, at))
        return {name for name, bit in flags.items() if hb.base_mode & bit}, hb.system_status

    base = {"CUSTOM_MODE_ENABLED", "STABILIZE_ENABLED", "MANUAL_INPUT_ENABLED"}
    assert heartbeat(STATE) == (base | {"SAFETY_ARMED"}, mav2.MAV_STATE_ACTIVE)
    disarmed = replace(STATE, armed=False)
    assert heartbeat(disarmed) == (base, mav2.MAV_STATE_STANDBY)
    assert heartbeat(replace(disarmed, mode="POSHOLD"), failsafe=True) == (base | {"GUIDED_ENABLED"},
                                                                          mav2.MAV_STATE_CRITICAL)


def test_a_message_the_simulator_cannot_send_is_refused_by_name():
    with pytest.raises(ValueError, match="cannot send RAW_IMU"):
        build_message("RAW_IMU", STATE, _at(None))
