"""Helpers for the vehicle tests: a companion link + telemetry facing an in-thread simulated ArduSub, and a plain
pymavlink peer of the simulator (a ground station, a joystick bridge)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.waiting import wait_until
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
def companion_and_sim(*, telemetry: bool = True, stale_after_s: float = 0.4, telemetry_settings: dict | None = None,
                      **sim_kwargs) -> Iterator[tuple[MavLink, VehicleTelemetry | None, SimVehicle]]:
    """Our link (udpin, as on a BlueOS vehicle) with telemetry attached (``telemetry_settings``: more of its
    configuration), and the sim sending to it."""
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    cfg = TelemetryConfig(stale_after_s=stale_after_s, **(telemetry_settings or {}))
    tel = VehicleTelemetry(link, cfg) if telemetry else None
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


class Peer:
    """A pymavlink peer of the simulator (ground station, joystick bridge) that records all it hears."""

    def __init__(self, port: int, system: int, component: int = 190) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=system,
                                               source_component=component, dialect="ardupilotmega")
        self.messages: list[tuple[float, mav2.MAVLink_message]] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() != "BAD_DATA":
                with self._lock:
                    self.messages.append((time.monotonic(), msg))

    def of_type(self, kind: str, since: float = 0.0) -> list[mav2.MAVLink_message]:
        with self._lock:
            return [m for t, m in self.messages if t >= since and m.get_type() == kind]

    def send(self, msg: mav2.MAVLink_message) -> None:
        with self._lock:  # pymavlink's writer is not thread-safe; only this test thread sends
            self.conn.mav.send(msg)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.conn.close()


@contextmanager
def sim_and_peer(system: int = 255, **sim_kwargs) -> Iterator[tuple[SimVehicle, Peer]]:
    port = free_udp_port()
    peer = Peer(port, system)
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", **sim_kwargs)
    sim.start()
    try:
        assert wait_until(lambda: peer.of_type("HEARTBEAT"), 5)
        yield sim, peer
    finally:
        sim.stop()
        peer.close()
