"""A writable on-board Downlink holding summary frames 3, 4 and 5, for the FTP tests of this folder."""

from __future__ import annotations

import pytest

from tests.conftest import free_udp_port
from tests.vehicle.surface_env import added, companion_link
from vehicle.camera.downlink import Downlink
from vehicle.settings import SurfaceConfig


@pytest.fixture
def companion():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000, push=False, ftp_writable=True))
    surface.start()
    for i in (3, 4, 5):
        surface.publish(added(i, [3, 4, 5][: i - 2]))
    yield port, surface
    surface.stop()
    link.stop()
