"""The companion's link and telemetry against the simulated ArduSub over real loopback UDP."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from companion.errors import MerlionError
from tests.conftest import REPO, free_udp_port, run_merlion
from tests.vehicle.sim_env import FAST_LINK, Transitions, companion_and_sim, quick_dive
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.link.message_rates import RateKeeper
from vehicle.sim.dive_profile import compile_profile, load_profile
from vehicle.sim.vehicle import SimVehicle, run_sim_vehicle


def _sim_time_now(sim) -> tuple[float, float]:
    """(companion wall time, simulator profile time) taken together."""
    return time.time(), time.monotonic() - sim._start


def test_rates_are_requested_and_depth_attitude_tracked():
    with companion_and_sim() as (link, tel, sim):
        heartbeats: list = []
        got_hb = threading.Event()
        sim.link.subscribe(lambda m: (heartbeats.append(m), got_hb.set()), ["HEARTBEAT"])
        assert link.wait_autopilot(5) and link.autopilot == (1, 1) and link.system_id == 1
        assert got_hb.wait(5)
        hb = heartbeats[0]
        assert (hb.get_srcSystem(), hb.get_srcComponent(), hb.type, hb.autopilot) == (1, 100, 30, 8)

        # SET_MESSAGE_INTERVAL for each wanted message arriving short of it, acknowledged; ATTITUDE_QUATERNION is
        # off by default. ATTITUDE comes at the wanted 10 Hz already: asked for only if the first second heard
        # under 8 of them
        assert wait_until(lambda: sim.interval("ATTITUDE_QUATERNION") == pytest.approx(0.1), 5)
        assert wait_until(lambda: len(tel.rates.method) == 6, 10)
        assert {n: m for n, m in tel.rates.method.items() if n != "ATTITUDE"} == dict.fromkeys(
            ["ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "SCALED_PRESSURE2", "SYSTEM_TIME"],
            "interval")
        assert tel.rates.method["ATTITUDE"] in ("as_found", "interval")
        assert (mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 31.0, 100000.0, mav2.MAV_RESULT_ACCEPTED) in sim.commands
        assert sim.interval("SCALED_PRESSURE2") == pytest.approx(0.2)
        quats = []
        link.subscribe(quats.append, ["ATTITUDE_QUATERNION"])

        assert tel.wait_for(lambda s: s.depth_m is not None and s.depth_m > 2.0, 10)
        assert wait_until(lambda: len(quats) >= 5, 5)
        latest = tel.latest
        assert latest.depth_source == "global_position_int" and latest.armed and latest.mode == "MANUAL"
        assert latest.lat == pytest.approx(1.25, abs=1e-4) and latest.battery_v is not None

        # half a second back, samples of every channel (5 Hz and faster) surround the asked time
        for lag in (0.5, 0.7):
            wall, sim_t = _sim_time_now(sim)
            pose = tel.pose_at(wall - lag)
            truth = sim.profile.state(sim_t - lag)
            assert not pose.stale and pose.age_s < 0.1
            assert pose.depth_m == pytest.approx(truth.depth, abs=0.1)  # 2 m/s descent: 0.1 m is 50 ms
            assert math.degrees(pose.roll) == pytest.approx(math.degrees(truth.roll), abs=0.5)
            assert math.degrees(pose.pitch) == pytest.approx(math.degrees(truth.pitch), abs=0.5)
            assert pose.down_m == pytest.approx(truth.depth, abs=0.1)


def test_silence_is_a_loss_then_recovery_and_frames_in_it_are_stale():
    with companion_and_sim(stale_after_s=0.3) as (link, tel, sim):
        seen = Transitions(link)
        assert seen.wait([True], 5)
        assert tel.wait_for(lambda s: s.depth_m is not None, 5)
        sim.silence(1.5)
        assert seen.wait([True, False], 5)
        pose = tel.pose_at(time.time())
        assert pose.stale and pose.depth_m is None and pose.q is None
        assert seen.wait([True, False, True], 5)
        assert tel.boot_clock.reboots == 0
        assert tel.wait_for(lambda s: True, 1) and wait_until(lambda: not tel.pose_at(time.time() - 0.1).stale, 3)


def test_reboot_restarts_boot_time_and_rates_are_asked_again():
    with companion_and_sim(reboot_s=0.8) as (link, tel, sim):
        seen = Transitions(link)
        assert seen.wait([True], 5)
        assert wait_until(lambda: sim.interval("ATTITUDE_QUATERNION") is not None, 5)
        assert tel.wait_for(lambda s: s.depth_m is not None, 5)
        assert wait_until(lambda: sim.time_boot_ms() > 1500, 5)  # so that the reboot takes boot time back
        sim.reboot()
        assert seen.wait([True, False, True], 8)
        assert wait_until(lambda: tel.boot_clock.reboots == 1, 5)
        # defaults after the reboot switched the quaternion off; the companion asks for it again
        assert wait_until(lambda: sim.interval("ATTITUDE_QUATERNION") == pytest.approx(0.1), 8)
        # a second into the new boot, telemetry surrounds a time half a second back: interpolated again
        assert wait_until(lambda: sim.time_boot_ms() > 1000, 3)
        wall, sim_t = _sim_time_now(sim)
        pose = tel.pose_at(wall - 0.5)
        assert not pose.stale and pose.age_s < 0.1
        assert pose.depth_m == pytest.approx(sim.profile.state(sim_t - 0.5).depth, abs=0.1)


def test_old_firmware_gets_request_data_stream():
    with companion_and_sim(message_interval=False) as (link, tel, sim):
        assert wait_until(lambda: sim.data_stream_requests, 10)
        assert wait_until(lambda: tel.rates.method.get("SCALED_PRESSURE2") == "data_stream", 10)
        assert wait_until(lambda: sim.interval("SCALED_PRESSURE2") == pytest.approx(0.2), 5)
        assert tel.rates.acks["ATTITUDE_QUATERNION"] == mav2.MAV_RESULT_UNSUPPORTED  # the first one asked


def test_rate_lowered_by_a_ground_station_is_asked_for_again():
    with companion_and_sim(telemetry=False) as (link, _tel, sim):
        keeper = RateKeeper(link, {"ATTITUDE": 20.0}, window_s=1.0, grace_s=0.5)  # above the default 10 Hz
        keeper.start()
        try:
            assert wait_until(lambda: keeper.requests["ATTITUDE"] == 1 and keeper.method.get("ATTITUDE"), 5)
            sim.set_rate("ATTITUDE", 1.0)  # the GCS wants it slower
            assert wait_until(lambda: keeper.requests["ATTITUDE"] >= 2, 8)
            assert wait_until(lambda: sim.interval("ATTITUDE") == pytest.approx(0.05), 3)
        finally:
            keeper.stop()


def _no_origin_dive():
    """Held at the surface a second, then down to 20 m, with no EKF origin: LOCAL_POSITION_NED never comes."""
    return compile_profile({"origin": None, "legs": [{"hold": {"s": 1.0}}, {"descend": {"to_m": 20, "rate_mps": 0.5}}]})


def test_a_rate_a_ground_station_raised_is_neither_lowered_nor_asked_for_again():
    """A GCS on the router set ATTITUDE to 50 Hz before the companion came (the last request wins for everyone):
    the companion, wanting 10 Hz, hears it arrive faster in its first second and never sends a request for it,
    not at first and not at the later checks, while it keeps asking for what falls short (LOCAL_POSITION_NED never
    comes without an origin: three requests, and ATTITUDE was checked at least as often by then)."""
    with companion_and_sim(telemetry_settings={"rate_grace_s": 0.5}, profile=_no_origin_dive(),
                           rates={"HEARTBEAT": 5.0, "ATTITUDE": 50.0}) as (_link, tel, sim):
        assert wait_until(lambda: tel.rates.requests["LOCAL_POSITION_NED"] >= 3, 15)
        asked = {int(c[1]) for c in sim.commands if c[0] == mav2.MAV_CMD_SET_MESSAGE_INTERVAL}
        assert mav2.MAVLINK_MSG_ID_ATTITUDE not in asked and mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT in asked
        assert sim.interval("ATTITUDE") == pytest.approx(0.02)
        assert tel.rates.method["ATTITUDE"] == "as_found" and tel.rates.requests["ATTITUDE"] == 0
        assert tel.rates.observed_hz("ATTITUDE") > 10.0


@pytest.mark.slow
def test_a_rate_left_as_found_is_asked_for_once_it_falls_short():
    """GLOBAL_POSITION_INT already arrives at the wanted 5 Hz when the companion comes, so it is left as found; then
    a ground station sets it back to ArduSub's default 3.2 Hz. At its next check the companion asks for 5 Hz: what
    it left alone must keep arriving at the share it was judged on (a listen too short to judge a 3.2 Hz stream
    once read it as 4.7 Hz, and the stream stayed at 3.2 Hz for good, since an asked-for message is only asked
    again below half its rate)."""
    # checks further apart than the 5 s window, so that each sees a whole window
    with companion_and_sim(telemetry_settings={"rate_grace_s": 6.0}, profile=_no_origin_dive(),
                           rates={"HEARTBEAT": 5.0, "GLOBAL_POSITION_INT": 5.0}) as (_link, tel, sim):
        assert wait_until(lambda: tel.rates.method.get("GLOBAL_POSITION_INT") == "as_found", 10)
        assert tel.rates.requests["GLOBAL_POSITION_INT"] == 0
        sim.set_rate("GLOBAL_POSITION_INT", 3.2)  # a ground station on the router lowers it: above half of 5 Hz
        assert wait_until(lambda: tel.rates.requests["GLOBAL_POSITION_INT"] == 1, 15)
        assert tel.rates.method["GLOBAL_POSITION_INT"] in ("interval", "data_stream")
        assert wait_until(lambda: sim.interval("GLOBAL_POSITION_INT") == pytest.approx(0.2), 3)
        asked = [c for c in sim.commands if c[0] == mav2.MAV_CMD_SET_MESSAGE_INTERVAL
                 and int(c[1]) == mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT]
        assert [c[2] for c in asked] == [200_000.0]


def test_sim_vehicle_command_runs_as_a_process_and_reboots_on_sigusr2():
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    from companion.config import TelemetryConfig

    tel = VehicleTelemetry(link, TelemetryConfig())
    tel.start()
    link.start()
    assert link.wait_open(5)
    proc = subprocess.Popen([sys.executable, "-m", "companion", "sim-vehicle", "--connect", f"udpout:127.0.0.1:{port}",
                             "--duration", "30", "--reboot-s", "1.5", "--rate", "HEARTBEAT=5", "--json"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = Transitions(link)
        assert seen.wait([True], 20), "no heartbeat from the sim-vehicle process"
        assert tel.wait_for(lambda s: s.depth_m is not None and s.mode is not None, 10)
        boot_ms: list[int] = []
        link.subscribe(lambda m: boot_ms.append(m.time_boot_ms), ["ATTITUDE"])
        # a reboot shows as boot time going back: let the first boot last a while
        assert wait_until(lambda: bool(boot_ms) and boot_ms[-1] > 1500, 10)
        proc.send_signal(signal.SIGUSR2)
        assert seen.wait([True, False, True], 10)
        assert wait_until(lambda: tel.boot_clock.reboots == 1, 5)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        tel.stop()
        link.stop()
    assert proc.returncode == 0, err
    assert '"reboots": 1' in out
    counters = json.loads(out.strip().splitlines()[-1])
    # our link (a camera component of system 1) was seen, as nothing else: no GCS, no MANUAL_CONTROL, no failsafe
    assert counters["peers"] == ["1/100"] and counters["manual_control_from"] == [] and counters["failsafes"] == []


def test_sim_vehicle_refuses_bad_arguments_in_one_line(tmp_path):
    bad = tmp_path / "dive.yaml"
    bad.write_text("legs:\n  - descend: {to_m: -3}\n")
    for args, needle in [
        (["--connect", "udp:nowhere"], "mavlink connection 'udp:nowhere'"),
        (["--connect", "udpout:127.0.0.1:9", "--profile", str(bad)], "to_m must be >= 0"),
        (["--connect", "udpout:127.0.0.1:9", "--pilot-timeout", "0"], "--pilot-timeout"),
    ]:
        result = run_merlion("sim-vehicle", *args, timeout=30)
        assert result.returncode == 2, result.stderr  # bad arguments and a bad profile alike
        lines = [ln for ln in result.stderr.splitlines() if ln.startswith("merlion: error:")]
        assert len(lines) == 1 and needle in lines[0], result.stderr


def test_profile_keyframes_match_hand_computed_dive():
    profile = quick_dive()
    assert profile.state(0.25).depth == 0.0
    assert profile.state(0.5 + 1.5).depth == pytest.approx(3.0)  # 1.5 s at 2 m/s
    s = profile.state(0.5 + 3.0 + 2.0)  # halfway along the first 4 m lane, heading north
    assert (s.north, s.east, s.depth) == pytest.approx((2.0, 0.0, 6.0))
    assert (s.vn, s.ve) == pytest.approx((1.0, 0.0)) and s.yaw == pytest.approx(0.0)
    s = profile.state(0.5 + 3.0 + 4.0 + 1.0)  # halfway across the 2 m step east
    assert (s.north, s.east) == pytest.approx((4.0, 1.0)) and math.degrees(s.yaw) == pytest.approx(90.0)
    assert s.lat == pytest.approx(1.25 + math.degrees(4.0 / 6378137.0))


def test_shipped_survey_profile_loads_and_dives():
    profile = load_profile(REPO / "config" / "dive" / "survey.yaml")
    depths = [profile.state(t).depth for t in range(0, int(profile.duration), 5)]
    assert max(depths) == pytest.approx(12.0) and depths[0] == 0.0
    assert profile.state(profile.duration - 1).mode == "SURFACE"
    with pytest.raises(MerlionError, match="unknown kind 'spiral'"):
        compile_profile({"legs": [{"spiral": {"turns": 3}}]})


def test_scheduled_silence_and_a_listening_sim():
    """``--silence-at/--silence-for`` as run_sim_vehicle does them, with the sim listening (udpin) this time."""
    port = free_udp_port()
    sim = SimVehicle(f"udpin:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0})
    link = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))  # our heartbeat lets the sim answer
    seen = Transitions(link)
    stop = threading.Event()
    runner = threading.Thread(target=lambda: run_sim_vehicle(sim, silence_at=1.0, silence_for=1.5, stop=stop))
    runner.start()
    link.start()
    try:
        assert seen.wait([True, False, True], 15)
        assert sim.link.autopilot is None  # the sim never took our camera heartbeat for an autopilot
    finally:
        stop.set()
        runner.join(10)
        link.stop()
    assert not runner.is_alive()
