"""MAVSDK (the C++ library behind many ground tools) as the client: camera discovery, captures, FTP, CRC.

Skipped when the ``mavsdk`` wheel (bundling libmavsdk) is not installed; ``pip install -e ".[test]"`` brings it.
"""

from __future__ import annotations

import threading
import time

import pytest

from companion.config import SurfaceConfig
from companion.vision.events import SummaryEvent
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import added, companion_link, summary_frame
from vehicle.camera.downlink import Downlink

mavsdk = pytest.importorskip("mavsdk")


def _until(check, timeout: float):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = check()
        if value:
            return value
        time.sleep(0.1)
    return check()


def _download(ftp, remote: str, folder: str, burst: bool):
    done = threading.Event()
    results = []

    def on_progress(result, _progress, _user):
        results.append(result)
        if result.name != "NEXT":
            done.set()

    ftp.download_async(remote, folder, burst, on_progress)
    assert done.wait(20), f"MAVSDK download of {remote} did not finish"
    return results[-1]


def test_mavsdk_finds_the_camera_sees_captures_and_downloads(tmp_path):
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.camera import Camera
    from mavsdk.plugins.ftp import Ftp, FtpResult

    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, push=False))
    surface.start()
    for i in (3, 4):
        surface.publish(added(i, [3, 4][: i - 2]))
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert sdk.add_any_connection(f"udpout://127.0.0.1:{port}").name == "SUCCESS"
        systems = _until(sdk.get_systems, 10)
        assert systems and systems[0].get_system_id() == 1
        system = systems[0]
        camera = Camera(system)
        cameras = _until(lambda: camera.camera_list().cameras, 10)
        assert [(c.component_id, c.vendor_name) for c in cameras] == [(100, "MERLION")]
        captures = []
        camera.subscribe_capture_info(lambda info, _u: captures.append(info))
        # a placed capture: one without a position has capture_result 0 (QGroundControl draws no marker for it),
        # which MAVSDK reports as is_success False (docs/surface-link.md)
        surface.publish(SummaryEvent("added", summary_frame(5, lat=1.2834), summary=[3, 4, 5]))
        assert _until(lambda: captures, 10)
        info = captures[0]
        assert (info.index, info.file_url, info.is_success) == (5, "mftp://summary/5.jpg", True)
        assert info.position.relative_altitude_m == pytest.approx(-12.5)
        assert info.position.latitude_deg == pytest.approx(1.2834)

        ftp = Ftp(system)
        ftp.set_target_compid(100)
        listing = {e.name: e.size_bytes for e in ftp.list_directory("/summary").entries}
        assert listing["4.jpg"] == len(surface.tree.read("/summary/4.jpg"))
        assert {"3.jpg", "5.jpg", "index.json", "full"} <= set(listing)
        for remote, burst in (("/summary/4.jpg", True), ("/summary/3.jpg", False)):
            assert _download(ftp, remote, str(tmp_path), burst) == FtpResult.SUCCESS
            local = tmp_path / remote.rsplit("/", 1)[1]
            assert local.read_bytes() == surface.tree.read(remote)
        assert ftp.are_files_identical(str(tmp_path / "4.jpg"), "/summary/4.jpg")  # our CRC-32 is theirs
    finally:
        sdk.destroy()
        surface.stop()
        link.stop()
