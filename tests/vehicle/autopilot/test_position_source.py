"""An ArduSub without a position source (no DVL, no USBL) never sends LOCAL_POSITION_NED: the companion asks for
it less and less often (exponential, capped back-off) and says once that there is no position source."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import SimVehicle


@pytest.mark.slow
def test_missing_local_position_backs_off_exponentially_and_is_announced_once():
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(position_wait_s=0), rate_options={"grace_s": 0.25, "backoff_max_s": 1.0})
    notices: list[tuple[str, int]] = []
    tel.on_notice(lambda text, severity: notices.append((text, severity)))
    tel.start()
    link.start()
    no_position_source = compile_profile({"legs": [{"hold": {"s": 60}}]})  # no origin: no DVL, no USBL
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", no_position_source, rates={"HEARTBEAT": 5.0})
    asked: list[float] = []
    sim.link.subscribe(lambda m: asked.append(time.monotonic()) if (
        m.command == mav2.MAV_CMD_SET_MESSAGE_INTERVAL and m.param1 == mav2.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
        else None, ["COMMAND_LONG"])
    sim.start()
    try:
        assert wait_until(lambda: len(asked) >= 6, 10), asked
        gaps = [b - a for a, b in zip(asked, asked[1:], strict=False)]
        # grace 0.25 s, then doubling: 0.25, 0.5, 1.0 (the cap), 1.0, ... A loaded machine delays an ask (the
        # next is timed from it) and never brings one much early, so each gap is held to its own nominal value:
        # no doubling would give 0.25 for the second, no cap 2.0 for the fourth
        for gap, nominal in zip(gaps, (0.25, 0.5, 1.0, 1.0, 1.0), strict=False):
            assert 0.8 * nominal <= gap <= nominal + 0.5, gaps
        assert tel.rates.missing == {"LOCAL_POSITION_NED"} and tel.latest.position_source is False
        assert notices == [("No position source (no DVL/USBL): depth only", mav2.MAV_SEVERITY_INFO)]
        # every other message the companion wants does arrive when asked for: nothing else is declared missing
        assert tel.wait_for(lambda s: s.depth_m is not None and s.roll is not None, 2)
        # an origin is set (as a ground station would; sent on our link here, the one the sim listens to): the
        # position comes, and is recorded as coming
        link.send(mav2.MAVLink_set_gps_global_origin_message(1, 12500000, 1038000000, 0, 0))
        assert tel.wait_for(lambda s: s.position_source is True and s.north_m is not None, 5)
        assert wait_until(lambda: not tel.rates.missing, 5)
        assert wait_until(lambda: len(notices) == 2, 5), notices  # and says so: the positions arrive now
        assert notices[1] == ("Position source found: positions arrive now", mav2.MAV_SEVERITY_INFO)
    finally:
        sim.stop()
        tel.stop()
        link.stop()
