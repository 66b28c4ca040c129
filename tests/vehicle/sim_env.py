"""Helpers for the vehicle tests: a companion link + telemetry facing an in-thread simulated ArduSub."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.dive_profile import DiveProfile, compile_profile
from vehicle.sim.vehicle import SimVehicle

FAST_LINK = {"heartbeat_timeout_s": 0.6, "reconnect_initial_s": 0.05, "reconnect_max_s": 0.2}


def quick_dive() -> DiveProfile:
    """A dive that changes fast enough to check in a few seconds: 2 m/s down to 6 m, then a short survey."""
    return compile_profile({"origin": {"lat": 1.25, "lon": 103.8, "after_s": 0}, "legs": [
        {"hold": {"s": 0.5}},
        {"descend": {"to_m": 6.0, "rate_mps": 2.0}},
        {"lawnmower": {"lanes": 2, "length_m": 4.0, "spacing_m": 2.0, "speed_mps": 1.0}},
        {"ascend": {"to_m": 0.0, "rate_mps": 2.0}},
    ]})


@contextmanager
def companion_and_sim(*, telemetry: bool = True, stale_after_s: float = 0.4, **sim_kwargs) -> Iterator[
        tuple[MavLink, VehicleTelemetry | None, SimVehicle]]:
    """Our link (udpin, as on a BlueOS vehicle) with telemetry attached, and the sim sending to it."""
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(stale_after_s=stale_after_s)) if telemetry else None
    if tel is not None:
        tel.start()
    link.start()
    assert link.wait_open(5)
    sim_kwargs.setdefault("profile", quick_dive())
    sim_kwargs.setdefault("rates", {"HEARTBEAT": 5.0})  # heartbeats faster than the short loss timeout
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", **sim_kwargs)
    sim.start()
    try:
        yield link, tel, sim
    finally:
        sim.stop()
        if tel is not None:
            tel.stop()
        link.stop()


class Transitions:
    """Records on_autopilot events and lets a test wait for a sequence of them."""

    def __init__(self, link: MavLink) -> None:
        self.events: list[bool] = []
        self._cv = threading.Condition()
        link.on_autopilot(self._on)

    def _on(self, alive: bool) -> None:
        with self._cv:
            self.events.append(alive)
            self._cv.notify_all()

    def wait(self, expected: list[bool], timeout: float = 10.0) -> bool:
        with self._cv:
            return self._cv.wait_for(lambda: self.events[: len(expected)] == expected, timeout)
