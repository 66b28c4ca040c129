"""A writable on-board Downlink holding summary frames 3, 4 and 5, for the FTP tests of this folder."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.conftest import free_udp_port
from tests.vehicle.surface_env import added, companion_link
from tests.vehicle.tether import PASSPHRASE
from vehicle.camera.downlink import Downlink
from vehicle.link.connection import MavLink
from vehicle.settings import MavlinkConfig, SurfaceConfig


def signed_companion_link(tmp_path: Path, port: int) -> MavLink:
    """The companion's link (1/100) on udpin ``port``, signing with the tests' passphrase; started and open."""
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100,
                                                            signing_key_file=str(key_file)))
    link.start()
    assert link.wait_open(5)
    return link


@contextmanager
def serving_frames(link: MavLink) -> Iterator[Downlink]:
    """A writable Downlink on ``link`` holding summary frames 3, 4 and 5; stops it and the link afterwards."""
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000, push=False, ftp_writable=True))
    surface.start()
    for i in (3, 4, 5):
        surface.publish(added(i, [3, 4, 5][: i - 2]))
    try:
        yield surface
    finally:
        surface.stop()
        link.stop()


@pytest.fixture
def companion():
    port = free_udp_port()
    with serving_frames(companion_link(port)) as surface:
        yield port, surface
