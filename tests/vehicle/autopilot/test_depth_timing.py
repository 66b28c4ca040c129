"""Depth tags during a 0.5 m/s descent at the real firmware's stream rates (GLOBAL_POSITION_INT ~3.2 Hz,
SCALED_PRESSURE2 1 Hz, nothing requested): each simulated frame's depth, looked up when the pipeline would tag it
(at once, or a little later), against the simulator's true depth at the frame's capture time."""

from __future__ import annotations

import time

import pytest

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import SimVehicle


@pytest.mark.slow
def test_depth_tags_within_5_cm_during_a_half_metre_per_second_descent_at_firmware_rates():
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(stale_after_s=1.0), request_rates=False)  # the firmware's rates
    tel.start()
    link.start()
    profile = compile_profile({"legs": [{"hold": {"s": 0.5}}, {"descend": {"to_m": 20.0, "rate_mps": 0.5}}]})
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", profile, rates={"HEARTBEAT": 5.0}, clock=time.time)
    sim.start()
    try:
        assert tel.wait_for(lambda s: s.depth_m is not None and s.depth_m > 0.3, 10)
        assert sim.interval("GLOBAL_POSITION_INT") == 1 / 3.2 and sim.interval("SCALED_PRESSURE2") == 1.0
        captures: list[float] = []
        errors: list[tuple[float, float, str]] = []
        while len(captures) < 60:  # about 4 s of frames, however slow the loop runs
            t = time.time()  # a frame is captured now ...
            captures.append(t)
            pose = tel.pose_at(t)  # ... and tagged at once (the newest depth sample is up to 0.31 s old)
            errors.append((abs(pose.depth_m - sim.state_at(t - sim._start).depth), t, "at once"))
            time.sleep(0.07)
        for t in captures:  # ... or tagged later, when samples on both sides of it have arrived
            pose = tel.pose_at(t)
            errors.append((abs(pose.depth_m - sim.state_at(t - sim._start).depth), t, "later"))
            assert pose.depth_source == "global_position_int"
        worst = max(errors)
        assert worst[0] <= 0.05, f"depth off by {worst[0]:.3f} m ({worst[2]})"
    finally:
        sim.stop()
        tel.stop()
        link.stop()
