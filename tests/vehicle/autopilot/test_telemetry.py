"""Telemetry from hand-made ArduSub messages on a real UDP link: depth sources, attitude, mode, time stamps."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK
from vehicle.autopilot.telemetry import VehicleTelemetry, depth_from_pressure
from vehicle.link.connection import MavLink

ARMED = mav2.MAV_MODE_FLAG_SAFETY_ARMED | mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


@pytest.fixture
def rig():
    """Our link + telemetry (fresh water), a fake autopilot (1/1) and a fake camera of another vendor (1/101)."""
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(fluid_density=997.0, stale_after_s=5.0), request_rates=False)
    tel.start()
    link.start()
    assert link.wait_open(5)
    ap = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=1), heartbeat=False, name="ap")
    other = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=101), heartbeat=False,
                    name="other")
    ap.start()
    other.start()
    assert ap.wait_open(5) and other.wait_open(5)
    ap.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, ARMED, 2, 4, 3))
    assert link.wait_autopilot(5)
    yield tel, ap, other
    other.stop()
    ap.stop()
    tel.stop()
    link.stop()


def test_pressure_to_depth_by_hand():
    # 5 m of sea water (1025 kg/m^3) adds 1025 * 9.80665 * 5 Pa = 502.59 hPa
    assert depth_from_pressure(1013.25 + 502.590812, 1025.0, 1013.25) == pytest.approx(5.0, abs=1e-6)
    assert depth_from_pressure(1013.25, 997.0, 1013.25) == 0.0


def test_depth_falls_back_from_pressure_and_prefers_global_position(rig):
    tel, ap, _ = rig
    assert tel.wait_for(lambda s: s.mode == "ALT_HOLD" and s.armed is True, 5)
    press = 1013.25 + 997.0 * 9.80665 * 3.0 / 100.0  # 3 m of fresh water
    ap.send(mav2.MAVLink_scaled_pressure2_message(1000, press, 0.0, 1500, 0))
    assert tel.wait_for(lambda s: s.depth_m is not None, 5)
    assert tel.latest.depth_m == pytest.approx(3.0, abs=1e-4) and tel.latest.depth_source == "scaled_pressure2"
    ap.send(mav2.MAVLink_global_position_int_message(1100, 0, 0, 0, -2500, 0, 0, 0, 9000))
    assert tel.wait_for(lambda s: s.depth_source == "global_position_int", 5)
    assert tel.latest.depth_m == pytest.approx(2.5) and tel.latest.lat is None  # 0/0: no EKF origin
    ap.send(mav2.MAVLink_scaled_pressure2_message(1200, press, 0.0, 1500, 0))  # now ignored for depth
    ap.send(mav2.MAVLink_vfr_hud_message(0.0, 0.0, 90, 0, -7.0, 0.0))
    ap.send(mav2.MAVLink_sys_status_message(0, 0, 0, 0, 15600, 500, 87, 0, 0, 0, 0, 0, 0))
    assert tel.wait_for(lambda s: s.battery_v is not None, 5)
    assert tel.latest.depth_m == pytest.approx(2.5) and tel.latest.depth_source == "global_position_int"
    assert (tel.latest.battery_v, tel.latest.battery_pct) == (15.6, 87)


def test_vfr_hud_is_the_last_resort_and_zero_without_origin_says_nothing(rig):
    tel, ap, _ = rig
    ap.send(mav2.MAVLink_attitude_message(600, 0.0, 0.0, 0.0, 0, 0, 0))  # VFR_HUD has no time: this places it
    ap.send(mav2.MAVLink_vfr_hud_message(0.0, 0.0, 45, 0, 0.0, 0.0))
    ap.send(mav2.MAVLink_vfr_hud_message(0.0, 0.0, 45, 0, -4.2, 0.0))
    assert tel.wait_for(lambda s: s.depth_m is not None, 5)
    assert tel.latest.depth_m == pytest.approx(4.2) and tel.latest.depth_source == "vfr_hud"
    assert tel.history._depth.times and len(tel.history._depth.times) == 1  # the 0.0 was not recorded


def test_only_the_autopilot_is_believed(rig):
    tel, ap, other = rig
    other.send(mav2.MAVLink_global_position_int_message(500, 0, 0, 0, -9000, 0, 0, 0, 0))
    other.send(mav2.MAVLink_attitude_message(500, 1.0, 1.0, 1.0, 0, 0, 0))
    ap.send(mav2.MAVLink_attitude_message(600, 0.1, -0.2, 0.3, 0, 0, 0))
    assert tel.wait_for(lambda s: s.roll is not None, 5)
    assert tel.latest.roll == pytest.approx(0.1) and tel.latest.depth_m is None


def test_a_yaw_a_hair_west_of_north_is_heading_0_not_360(rig):
    tel, ap, _ = rig
    ap.send(mav2.MAVLink_attitude_message(600, 0.0, 0.0, -1e-17, 0, 0, 0))  # -1e-17 % 360.0 is 360.0 in Python
    assert tel.wait_for(lambda s: s.heading_deg is not None, 5)
    assert tel.latest.heading_deg == 0.0
    ap.send(mav2.MAVLink_attitude_message(700, 0.0, 0.0, -math.pi / 2, 0, 0, 0))
    assert tel.wait_for(lambda s: s.heading_deg is not None and s.heading_deg > 1.0, 5)
    assert tel.latest.heading_deg == pytest.approx(270.0)


def test_samples_are_placed_by_autopilot_time_not_arrival(rig):
    tel, ap, _ = rig
    # sent back to back: they arrive together, but the autopilot measured them 200 ms apart
    ap.send(mav2.MAVLink_global_position_int_message(10_000, 12_500_000, 1_038_000_000, -1000, -1000, 0, 0, 0, 0))
    ap.send(mav2.MAVLink_global_position_int_message(10_200, 12_500_200, 1_038_000_400, -2000, -2000, 0, 0, 0, 0))
    ap.send(mav2.MAVLink_attitude_quaternion_message(10_000, 1.0, 0.0, 0.0, 0.0, 0, 0, 0, [0.0] * 4))
    h = math.radians(45)
    ap.send(mav2.MAVLink_attitude_quaternion_message(10_200, math.cos(h), 0.0, 0.0, math.sin(h), 0, 0, 0, [0.0] * 4))
    assert tel.wait_for(lambda s: s.heading_deg is not None and s.heading_deg > 80, 5)
    t_mid = tel.boot_clock.to_local(10_100)
    assert tel.boot_clock.to_local(10_200) - t_mid == pytest.approx(0.1, abs=1e-5)
    pose = tel.pose_at(t_mid)
    assert pose.depth_m == pytest.approx(1.5, abs=1e-4) and pose.depth_source == "global_position_int"
    assert pose.lat == pytest.approx(1.25001, abs=1e-9) and pose.lon == pytest.approx(103.80002, abs=1e-9)
    assert pose.alt_m == pytest.approx(-1.5, abs=1e-4)
    assert math.degrees(pose.yaw) == pytest.approx(45.0, abs=1e-3)  # halfway between 0 and 90 deg by slerp
    assert tel.latest.lat == pytest.approx(1.25002)
