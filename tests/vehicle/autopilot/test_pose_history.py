"""Pose lookup against hand-computed values: linear depth/position, slerp, nearest-sample age, stale tagging."""

from __future__ import annotations

import math

import pytest

from vehicle.autopilot.pose_history import PoseHistory, euler_to_quaternion, quaternion_to_euler, slerp


def _yaw_q(deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def test_depth_and_position_are_interpolated_linearly():
    h = PoseHistory(stale_after_s=1.0)
    h.add_depth(100.0, 2.0, "global_position_int")
    h.add_depth(100.5, 3.0, "global_position_int")
    h.add_local_position(100.0, 1.0, -2.0, 2.0)
    h.add_local_position(100.5, 2.0, -4.0, 3.0)
    pose = h.pose_at(100.2)
    assert not pose.stale
    assert pose.depth_m == pytest.approx(2.4)
    assert (pose.north_m, pose.east_m, pose.down_m) == pytest.approx((1.4, -2.8, 2.4))
    assert pose.age_s == pytest.approx(0.2)
    assert pose.depth_source == "global_position_int"
    assert pose.q is None and pose.roll is None  # no attitude was ever given: none is invented


def test_attitude_is_slerped():
    h = PoseHistory(stale_after_s=1.0)
    h.add_attitude(10.0, _yaw_q(0))
    h.add_attitude(11.0, _yaw_q(90))
    pose = h.pose_at(10.25)
    # a quarter of the way from 0 to 90 deg of yaw is 22.5 deg: q = (cos 11.25deg, 0, 0, sin 11.25deg)
    assert pose.q == pytest.approx((math.cos(math.radians(11.25)), 0, 0, math.sin(math.radians(11.25))))
    assert math.degrees(pose.yaw) == pytest.approx(22.5)
    assert pose.heading_deg == pytest.approx(22.5)
    assert pose.roll == pytest.approx(0.0, abs=1e-12)


def test_slerp_takes_the_short_way_and_keeps_unit_length():
    # 350 deg -> 10 deg of yaw: halfway is 0 deg (north), not 180 deg
    q = slerp(_yaw_q(350), _yaw_q(10), 0.5)
    assert abs(q[0]) == pytest.approx(1.0) and q[1:] == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert quaternion_to_euler(q)[2] == pytest.approx(0.0, abs=1e-9)
    q = slerp(_yaw_q(0), tuple(-c for c in _yaw_q(60)), 0.5)  # -q is the same rotation
    assert math.degrees(quaternion_to_euler(q)[2]) == pytest.approx(30.0)
    assert sum(c * c for c in q) == pytest.approx(1.0)
    roll_q = euler_to_quaternion(math.radians(20), 0, 0)
    assert roll_q == pytest.approx((math.cos(math.radians(10)), math.sin(math.radians(10)), 0, 0))


def test_euler_round_trip():
    angles = (0.3, -0.2, 2.5)
    assert quaternion_to_euler(euler_to_quaternion(*angles)) == pytest.approx(angles)


def test_stale_poses_carry_nothing():
    h = PoseHistory(stale_after_s=0.5)
    h.add_depth(50.0, 4.0, "scaled_pressure2")
    h.add_attitude(50.0, _yaw_q(45))
    pose = h.pose_at(50.8)
    assert pose.stale and pose.age_s == pytest.approx(0.8)
    assert pose.depth_m is None and pose.q is None and pose.heading_deg is None
    early = h.pose_at(49.0)
    assert early.stale
    assert h.pose_at(50.4).depth_m == 4.0  # within the limit the nearest sample is used as is, no extrapolation


def test_a_gap_in_telemetry_is_stale_in_its_middle():
    h = PoseHistory(stale_after_s=0.5)
    h.add_depth(0.0, 1.0, "global_position_int")
    h.add_depth(3.0, 4.0, "global_position_int")
    assert h.pose_at(1.5).stale  # both neighbours 1.5 s away: no interpolation across the outage
    assert h.pose_at(2.6).depth_m == pytest.approx(3.6)


def test_nothing_at_all_is_stale():
    pose = PoseHistory().pose_at(123.0)
    assert pose.stale and math.isinf(pose.age_s) and pose.time == 123.0


def test_depth_source_follows_the_nearer_sample_and_old_samples_are_pruned():
    h = PoseHistory(stale_after_s=1.0, history_s=10.0)
    h.add_depth(0.0, 1.0, "vfr_hud")
    h.add_depth(1.0, 2.0, "global_position_int")
    assert h.pose_at(0.2).depth_source == "vfr_hud"
    assert h.pose_at(0.8).depth_source == "global_position_int"
    for i in range(2, 40):
        h.add_depth(float(i), float(i), "global_position_int")
    assert h.pose_at(0.0).stale  # pruned beyond history_s
    assert h.pose_at(39.0).depth_m == 39.0


def test_heading_alone_interpolates_through_north():
    h = PoseHistory(stale_after_s=1.0)
    h.add_depth(0.0, 1.0, "vfr_hud")
    h.add_heading(0.0, 350.0)
    h.add_heading(1.0, 10.0)
    assert h.pose_at(0.5).heading_deg % 360.0 == pytest.approx(0.0, abs=1e-9)
    assert h.pose_at(0.75).heading_deg == pytest.approx(5.0)


def test_headings_stay_in_0_to_360_also_a_hair_west_of_north():
    h = PoseHistory(stale_after_s=1.0)
    h.add_depth(0.0, 1.0, "vfr_hud")
    h.add_heading(0.0, -1e-15)  # as added (% 360.0 alone kept 360.0)
    h.add_heading(1.0, 0.0)
    assert [h.pose_at(t).heading_deg for t in (0.0, 0.5, 1.0)] == [0.0, 0.0, 0.0]
    q = PoseHistory(stale_after_s=1.0)
    q.add_depth(0.0, 1.0, "vfr_hud")
    q.add_attitude(0.0, _yaw_q(-1e-15))  # from the attitude quaternion
    assert q.pose_at(0.0).heading_deg == 0.0


def test_history_keeps_pruning_after_a_reboot_clears_it():
    """After clear() (an autopilot reboot) times start again near zero; old samples must still be dropped."""
    h = PoseHistory(stale_after_s=1.0, history_s=2.0)
    for i in range(1000):  # an uptime of 100 s before the reboot
        h.add_depth(i * 0.1, 5.0, "scaled_pressure2")
    h.clear()
    for i in range(500):  # 50 s of the new boot: still below the old newest time
        h.add_depth(i * 0.1, 6.0, "scaled_pressure2")
    kept = len(h._depth.times)  # the only window onto memory use
    assert kept <= 2 * 2.0 / 0.1 + 2, f"{kept} samples kept for a 2 s history"
    assert h.pose_at(49.9).depth_m == pytest.approx(6.0)


def test_depth_with_vertical_speed_moves_on_past_the_newest_sample_and_curves_between_samples():
    h = PoseHistory(stale_after_s=0.5)
    h.add_depth(10.0, 2.0, "global_position_int", 0.5)
    h.add_depth(10.3, 2.15, "global_position_int", 0.5)
    assert h.pose_at(10.5).depth_m == pytest.approx(2.25)  # 0.2 s after the newest at 0.5 m/s down
    assert h.pose_at(10.1).depth_m == pytest.approx(2.05)  # constant speed: the curve is the straight line
    assert h.pose_at(11.0).stale  # never further than the stale limit
    # from holding (0 m/s) to descending: the Hermite curve follows the speeds, not the chord
    h.add_depth(20.0, 3.0, "global_position_int", 0.0)
    h.add_depth(21.0, 3.25, "global_position_int", 0.5)
    assert h.pose_at(20.5).depth_m == pytest.approx(3.0625)  # chord would say 3.125
    # a source without speed (pressure) is held, not extrapolated
    p = PoseHistory(stale_after_s=0.5)
    p.add_depth(1.0, 4.0, "scaled_pressure2")
    assert p.pose_at(1.3).depth_m == 4.0
