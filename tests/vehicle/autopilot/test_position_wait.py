"""ArduSub's EKF sets its origin (and LOCAL_POSITION_NED starts) ~16 s after boot: the companion says "no position
source" only once the autopilot has been up ``telemetry.position_wait_s`` without positions, and when positions
arrive after it was said, it takes it back everywhere: the status flag, a STATUSTEXT, and the surface page."""

from __future__ import annotations

import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from companion.topside.gallery import Gallery
from companion.topside.tool import SurfaceOptions, SurfaceTool
from tests.companion.surface_peer import CompanionPeer
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import NO_POSITION_TEXT, POSITION_FOUND_TEXT, VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import SimVehicle

FAST_RATES = {"grace_s": 0.25, "backoff_max_s": 1.0}  # LOCAL_POSITION_NED given up on ~1 s after asking


def _watch(port: int, wait_s: float) -> tuple[MavLink, VehicleTelemetry, list[tuple[str, int]]]:
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(position_wait_s=wait_s), rate_options=FAST_RATES)
    notices: list[tuple[str, int]] = []
    tel.on_notice(lambda text, severity: notices.append((text, severity)))
    tel.start()
    link.start()
    return link, tel, notices


def test_positions_that_start_with_the_ekf_origin_are_never_called_missing():
    port = free_udp_port()
    link, tel, notices = _watch(port, wait_s=8.0)
    # the origin 4 s after boot (16 s in ArduSub SITL, shortened); the rates give up on it well before that
    dive = compile_profile({"origin": {"lat": 1.2644, "lon": 103.8222, "after_s": 4.0},
                            "legs": [{"hold": {"s": 60}}]})
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", dive, rates={"HEARTBEAT": 5.0})
    sim.start()
    try:
        assert wait_until(lambda: "LOCAL_POSITION_NED" in tel.rates.missing, 4), "the rates never gave up on it"
        assert tel.latest.position_source is None and notices == []  # the autopilot is up < 8 s: not said yet
        assert tel.wait_for(lambda s: s.position_source is True and s.north_m is not None, 8)
        time.sleep(0.5)
        assert notices == [] and tel.latest.position_source is True
    finally:
        sim.stop()
        tel.stop()
        link.stop()


def test_no_position_source_is_said_after_the_wait_and_taken_back_when_positions_come():
    port = free_udp_port()
    link, tel, notices = _watch(port, wait_s=2.0)
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", compile_profile({"legs": [{"hold": {"s": 60}}]}),
                     rates={"HEARTBEAT": 5.0})  # no origin: no DVL, no USBL
    start = time.monotonic()
    sim.start()
    try:
        assert tel.wait_for(lambda s: s.position_source is False, 10)
        assert time.monotonic() - start >= 2.0
        assert wait_until(lambda: notices, 5) and notices == [(NO_POSITION_TEXT, mav2.MAV_SEVERITY_INFO)]
        link.send(mav2.MAVLink_set_gps_global_origin_message(1, 12500000, 1038000000, 0, 0))  # as a GCS would
        assert tel.wait_for(lambda s: s.position_source is True and s.north_m is not None, 5)
        assert wait_until(lambda: len(notices) == 2, 5), notices
        assert notices[1] == (POSITION_FOUND_TEXT, mav2.MAV_SEVERITY_INFO)
    finally:
        sim.stop()
        tel.stop()
        link.stop()


def test_the_surface_page_stops_showing_no_position_source_once_positions_arrive(tmp_path):
    port = free_udp_port()
    tool = SurfaceTool(SurfaceOptions(connect=f"udpin:127.0.0.1:{port}"), Gallery(tmp_path))
    stop = threading.Event()
    thread = threading.Thread(target=tool.run, args=(stop,), daemon=True)
    thread.start()
    peer = CompanionPeer(port)

    def texts() -> list[str]:
        return [line["text"] for line in tool.snapshot()["companion"]["statustext"]]

    try:
        # until the tool answers (its heartbeat) it may not be listening yet, and a STATUSTEXT is sent once
        assert wait_until(lambda: peer.heartbeat() or any(m.get_type() == "HEARTBEAT" for m in peer.received), 10)
        peer.send(mav2.MAVLink_statustext_message(mav2.MAV_SEVERITY_INFO, NO_POSITION_TEXT.encode()))
        assert wait_until(lambda: NO_POSITION_TEXT in texts(), 10), texts()
        peer.send(mav2.MAVLink_statustext_message(mav2.MAV_SEVERITY_INFO, POSITION_FOUND_TEXT.encode()))
        assert wait_until(lambda: POSITION_FOUND_TEXT in texts(), 10), texts()
        assert NO_POSITION_TEXT not in texts()
    finally:
        stop.set()
        thread.join(10)
        peer.close()
        tool.close()
