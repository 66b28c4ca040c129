"""Fixtures of the live companion's tests that run it against a simulated dive on one UDP hub."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Listener
from vehicle.sim.vehicle import SimVehicle


@pytest.fixture
def dive():
    """The hub (the vehicle's router), the simulated ArduSub, a listener and a ground station, all on it."""
    listener = Listener()
    hub = UdpHub(outputs=[("127.0.0.1", listener.port)]).start()
    sim = SimVehicle(hub.url)
    sim.start()
    gcs = mavutil.mavlink_connection(f"udpout:{hub.host}:{hub.port}", source_system=255, source_component=190,
                                     dialect="ardupilotmega")
    gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    yield hub, gcs, listener
    gcs.close()
    sim.stop()
    hub.stop()
    listener.close()
