"""Fixtures of the live companion's tests that run it against a simulated dive on one UDP hub."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from tests.companion.live_harness import simulated_vehicle


@pytest.fixture
def vehicle():
    """A UDP hub (the router), the simulated ArduSub on it, and a ground-station listener on it."""
    with simulated_vehicle() as parts:
        yield parts


@pytest.fixture
def dive(vehicle):
    """The hub (the vehicle's router), the simulated ArduSub, a listener and a ground station, all on it."""
    hub, _sim, listener = vehicle
    gcs = mavutil.mavlink_connection(f"udpout:{hub.host}:{hub.port}", source_system=255, source_component=190,
                                     dialect="ardupilotmega")
    gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    yield hub, gcs, listener
    gcs.close()
