"""The simulator does what the real ArduSub firmware does (REFERENCE.md): default streams, rate requests, when the
EKF fields become valid, and depth holding under MANUAL_CONTROL (the failsafes: test_failsafes.py). Peers are
plain pymavlink connections on loopback UDP, as a ground station or a joystick bridge would be."""

from __future__ import annotations

import collections
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.vehicle.sim_env import sim_and_peer
from tests.waiting import wait_until
from vehicle.errors import UserError as MerlionError
from vehicle.sim.dive_profile import compile_profile


def _profile(origin: dict | None = None, armed: bool = True):
    return compile_profile({"origin": origin, "armed": armed, "legs": [{"hold": {"s": 2.0, "mode": "ALT_HOLD"}},
                                                                        {"descend": {"to_m": 20, "rate_mps": 0.5}}]})


def test_default_streams_without_any_request_and_no_position_before_the_ekf_origin():
    origin = {"lat": 1.25, "lon": 103.8, "after_s": 2.0}
    with sim_and_peer(profile=_profile(origin)) as (sim, peer):
        start = time.monotonic()
        time.sleep(1.9)
        window = time.monotonic() - start
        counts = collections.Counter(m.get_type() for t, m in peer.messages if t >= start)
        # the measured ArduSub defaults: 10 Hz, 10 Hz, 3.2 Hz, 1 Hz (counts over ~1.9 s, loose for a busy machine)
        assert 10 * window * 0.7 <= counts["ATTITUDE"] <= 10 * window + 2
        assert 10 * window * 0.7 <= counts["VFR_HUD"] <= 10 * window + 2
        assert 4 <= counts["GLOBAL_POSITION_INT"] <= 8
        for name in ("SYS_STATUS", "SCALED_PRESSURE", "SCALED_PRESSURE2"):
            assert 1 <= counts[name] <= 3, name
        assert counts["LOCAL_POSITION_NED"] == 0 and counts["ATTITUDE_QUATERNION"] == 0
        # before the EKF origin (2 s after boot, when the descent also starts): relative_alt valid, position and
        # MSL altitudes 0, no LOCAL_POSITION_NED; judged by when each message was sent, not by when the test looks
        early = [m for m in peer.of_type("GLOBAL_POSITION_INT") if m.time_boot_ms < 2000]
        assert early and all((m.lat, m.lon, m.alt) == (0, 0, 0) for m in early)
        booted = time.monotonic() - sim.time_boot_ms() / 1000.0  # the boot on the peer's clock (to 1 ms)
        hud = peer.of_type("VFR_HUD")
        assert len(hud) >= 10 and all(m.alt == 0 for t, m in peer.messages
                                      if m.get_type() == "VFR_HUD" and t < booted + 1.99)

        def after_origin() -> list:
            return [m for m in peer.of_type("GLOBAL_POSITION_INT") if m.time_boot_ms > 2600]

        assert wait_until(after_origin, 3)
        assert after_origin()[-1].lat == pytest.approx(1.25e7, abs=100)
        assert wait_until(lambda: peer.of_type("LOCAL_POSITION_NED"), 2)
        hb = peer.of_type("HEARTBEAT")[0]
        assert (hb.get_srcSystem(), hb.get_srcComponent(), hb.type) == (1, 1, mav2.MAV_TYPE_SUBMARINE)


def test_without_a_position_source_no_position_until_a_ground_station_sets_an_origin():
    with sim_and_peer(profile=_profile(None)) as (sim, peer):
        time.sleep(0.8)
        assert not peer.of_type("LOCAL_POSITION_NED")
        assert all((m.lat, m.alt) == (0, 0) and m.relative_alt <= 0 for m in peer.of_type("GLOBAL_POSITION_INT"))
        peer.send(mav2.MAVLink_set_gps_global_origin_message(1, 12500000, 1038000000, 5000, 0))
        assert wait_until(lambda: peer.of_type("LOCAL_POSITION_NED"), 2)
        assert wait_until(lambda: any(m.lat == 12500000 for m in peer.of_type("GLOBAL_POSITION_INT")), 2)


def test_set_message_interval_is_acked_and_the_last_request_from_any_peer_wins():
    with sim_and_peer(profile=_profile(None)) as (sim, peer):
        def interval(us: float, system: int) -> None:
            msg = mav2.MAVLink_command_long_message(1, 1, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                    mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, us, 0, 0, 0, 0, 0)
            peer.conn.mav.srcSystem = system  # a second ground station on the same router
            peer.send(msg)

        interval(100_000, 255)
        assert wait_until(lambda: sim.interval("GLOBAL_POSITION_INT") == pytest.approx(0.1), 2)
        interval(1_000_000, 254)
        assert wait_until(lambda: sim.interval("GLOBAL_POSITION_INT") == pytest.approx(1.0), 2)
        acks = [a for a in peer.of_type("COMMAND_ACK") if a.command == mav2.MAV_CMD_SET_MESSAGE_INTERVAL]
        assert wait_until(lambda: len([a for a in peer.of_type("COMMAND_ACK")
                                       if a.command == mav2.MAV_CMD_SET_MESSAGE_INTERVAL]) == 2, 2), acks
        assert {a.result for a in peer.of_type("COMMAND_ACK")} == {mav2.MAV_RESULT_ACCEPTED}
        interval(0, 254)  # 0: back to the default
        assert wait_until(lambda: sim.interval("GLOBAL_POSITION_INT") == pytest.approx(1 / 3.2), 2)


def test_depth_hold_in_alt_hold_and_manual_control_z_below_500_descends():
    with sim_and_peer(profile=_profile(None)) as (sim, peer):
        peer.send(mav2.MAVLink_set_mode_message(1, mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 2))  # ALT_HOLD
        for _ in range(3):
            peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0))  # full down
            time.sleep(0.1)
        assert wait_until(lambda: sim.state().depth > 0.5, 3)
        assert sim.state().vd == pytest.approx(1.0)  # PILOT_SPEED_DN 0: PILOT_SPEED_UP's 100 cm/s
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))  # neutral: hold
        assert wait_until(lambda: sim.state().vd == 0.0, 2)
        held, since = sim.state().depth, sim.time_boot_ms()
        time.sleep(0.3)
        peer.send(mav2.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))
        assert sim.state().depth == pytest.approx(held, abs=1e-3) and sim.state().mode == "ALT_HOLD"

        def reported() -> list:  # sent while holding, however late the test reads them
            return [m for m in peer.of_type("GLOBAL_POSITION_INT") if m.time_boot_ms > since]

        assert wait_until(reported, 2)
        assert reported()[-1].relative_alt == pytest.approx(-held * 1000, abs=5)


def test_origin_delay_is_read_from_the_profile_and_checked():
    legs = [{"hold": {"s": 1}}]
    assert compile_profile({"origin": {"lat": 1, "lon": 2}, "legs": legs}).origin.after_s == 16.0  # as in SITL
    assert compile_profile({"origin": {"lat": 1, "lon": 2, "after_s": 0}, "legs": legs}).origin.after_s == 0.0
    with pytest.raises(MerlionError, match="origin.after_s must be >= 0"):
        compile_profile({"origin": {"lat": 1, "lon": 2, "after_s": -1}, "legs": legs})
    with pytest.raises(MerlionError, match="origin needs numeric lat and lon"):
        compile_profile({"origin": {"lat": 1, "lon": 2, "after_s": "soon"}, "legs": legs})
