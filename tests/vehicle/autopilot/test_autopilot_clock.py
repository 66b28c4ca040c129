"""Every frame's pose carries the autopilot's clocks (time_boot_ms, SYSTEM_TIME's UTC) beside the companion's, so
its time survives a companion clock that is wrong or jumps (a vehicle without GPS time)."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink

ARMED = mav2.MAV_MODE_FLAG_SAFETY_ARMED | mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
AUTOPILOT_UTC_US = 1_780_000_000_000_000  # the autopilot's GPS time at its boot + 10 s (2026)
WRONG_BY_S = -400 * 86400.0  # the companion booted without network time: its clock is 400 days behind


class SteppedClock:
    """The companion's wall clock, off by ``error`` seconds, which the test can step (as NTP or a user would)."""

    def __init__(self, error: float) -> None:
        self.error = error

    def __call__(self) -> float:
        return time.time() + self.error


@pytest.fixture
def rig():
    port = free_udp_port()
    clock = SteppedClock(WRONG_BY_S)
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(stale_after_s=5.0), clock=clock, request_rates=False)
    tel.start()
    link.start()
    assert link.wait_open(5)
    ap = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=1), heartbeat=False, name="ap")
    ap.start()
    assert ap.wait_open(5)
    ap.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, ARMED, 2, 4, 3))
    assert link.wait_autopilot(5)
    yield tel, ap, clock
    ap.stop()
    tel.stop()
    link.stop()


def _attitude(ap: MavLink, boot_ms: int) -> None:
    ap.send(mav2.MAVLink_attitude_message(boot_ms, 0.0, 0.0, 0.5, 0, 0, 0))


def test_pose_carries_boot_time_and_autopilot_utc_through_a_wrong_then_stepped_companion_clock(rig):
    tel, ap, clock = rig
    _attitude(ap, 9_000)
    assert tel.wait_for(lambda s: s.yaw is not None, 5)
    before_utc = tel.pose_at(tel.boot_clock.to_local(9_500))
    assert before_utc.time_boot_ms == 9_500 and before_utc.autopilot_unix_usec is None  # no SYSTEM_TIME yet
    ap.send(mav2.MAVLink_system_time_message(AUTOPILOT_UTC_US, 10_000))
    assert tel.wait_for(lambda s: s.autopilot_utc is not None, 5)
    _attitude(ap, 10_000)

    t = tel.boot_clock.to_local(10_250)  # a frame captured 250 ms after that SYSTEM_TIME, on the wrong clock
    pose = tel.pose_at(t)
    assert pose.time == t and abs(t - time.time() - WRONG_BY_S) < 60  # the companion's own (wrong) time is kept
    assert pose.time_boot_ms == 10_250
    assert pose.autopilot_unix_usec == AUTOPILOT_UTC_US + 250_000  # the true time, whatever the companion thinks

    clock.error = 0.0  # network time arrives: the companion's clock jumps 400 days forward
    for boot_ms in range(11_000, 11_700, 100):  # a run of samples moves the boot-time mapping to the new clock
        _attitude(ap, boot_ms)
    assert tel.wait_for(lambda s: abs(tel.boot_clock.offset - (time.time() - 11.6)) < 5, 5)
    t2 = tel.boot_clock.to_local(11_500)
    pose2 = tel.pose_at(t2)
    assert abs(t2 - time.time()) < 60  # now on the right clock
    assert pose2.time_boot_ms == 11_500 and pose2.autopilot_unix_usec == AUTOPILOT_UTC_US + 1_500_000
    assert pose2.to_dict()["autopilot_unix_usec"] == AUTOPILOT_UTC_US + 1_500_000  # what the store's sidecar keeps


def test_an_autopilot_reboot_forgets_its_old_utc(rig):
    tel, ap, _ = rig
    ap.send(mav2.MAVLink_system_time_message(AUTOPILOT_UTC_US, 10_000))
    _attitude(ap, 10_000)
    assert tel.wait_for(lambda s: s.autopilot_utc is not None and s.yaw is not None, 5)
    assert tel.pose_at(tel.boot_clock.to_local(10_000)).autopilot_unix_usec == AUTOPILOT_UTC_US
    _attitude(ap, 2_000)  # time_boot_ms went back: the autopilot rebooted and has no UTC yet
    assert tel.wait_for(lambda s: s.autopilot_reboots == 1, 5)
    pose = tel.pose_at(tel.boot_clock.to_local(2_000))
    assert pose.time_boot_ms == 2_000 and pose.autopilot_unix_usec is None
