"""Operator marks over MAVLink FTP: /config/marks.json is validated, handed to the app, refused with a NAK."""

from __future__ import annotations

import json

from pymavlink import mavftp

from companion.config import SurfaceConfig
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link, ground_station
from vehicle.camera.downlink import Downlink


def _settings() -> mavftp.MAVFTPSettings:
    values = {"debug": 0, "pkt_loss_tx": 0, "pkt_loss_rx": 0, "max_backlog": 5, "burst_read_size": 239,
              "write_size": 80, "write_qsize": 5, "idle_detection_time": 1.5, "read_retry_time": 0.6,
              "retry_time": 0.4}
    return mavftp.MAVFTPSettings([(k, type(v), v) for k, v in values.items()])


def test_uploading_marks_reaches_the_app_and_a_refusal_is_a_nak(companion, tmp_path):
    port, surface = companion
    got = []

    def on_marks(like: list[int], unlike: list[int]) -> None:
        if 99 in like + unlike:
            raise ValueError("image 99 is not held")
        got.append((like, unlike))

    surface.on_marks_changed(on_marks)
    local = tmp_path / "marks.json"
    gcs = ground_station(port)
    try:
        client = mavftp.MAVFTP(gcs, 1, 100, settings=_settings())
        local.write_text('{"like": [3, 5], "unlike": [4]}')
        client.cmd_put([str(local), "/config/marks.json"])
        assert client.process_ftp_reply("put", timeout=10).error_code == mavftp.FtpError.Success
        assert got == [([3, 5], [4])]
        assert json.loads(surface.tree.read("/config/marks.json")) == {"like": [3, 5], "unlike": [4]}
        for bad in ('{"like": [99]}', '{"like": [3], "unlike": [3]}'):  # the app's refusal, the parser's
            local.write_text(bad)
            client.cmd_put([str(local), "/config/marks.json"])
            client.process_ftp_reply("put", timeout=10)  # mavftp reports no NAK of the closing request
        assert surface.ftp.naks  # the refusals went back to the client as NAKs
        assert got == [([3, 5], [4])]
        assert json.loads(surface.tree.read("/config/marks.json")) == {"like": [3, 5], "unlike": [4]}
    finally:
        gcs.close()


def test_marks_are_not_writable_unless_the_tree_is():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000, push=False, ftp_writable=False))
    try:
        surface.set_marks([1], [2])
        assert json.loads(surface.tree.read("/config/marks.json")) == {"like": [1], "unlike": [2]}
        assert not surface.ftp.writable
    finally:
        link.stop()
