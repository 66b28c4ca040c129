"""`merlion surface --signing-key` acts only on what the signed companion sends: an unsigned pymavlink attacker
beside it (first claiming to be another camera, then claiming the companion's own ids) changes nothing on the
page or in the gallery, and every message it sent is counted."""

from __future__ import annotations

import json
import socket
import time
from contextlib import contextmanager
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig, SurfaceConfig
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import summary_frame
from tests.companion.topside.live_page import page_state, surface_with_page
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.camera.captures import captured_message, trimmed_text
from vehicle.camera.downlink import Downlink
from vehicle.camera.status import push_marker
from vehicle.camera.thumbnails import make_thumbnail
from vehicle.link.connection import MavLink
from vehicle.protocol.image_push import push_messages

DIVE = "0a1b2c3d"


@contextmanager
def signed_companion(port: int, key: Path):
    """The real companion side (system 1, component 100) signing every message with ``key``."""
    link = MavLink(f"udpout:127.0.0.1:{port}",
                   MavlinkConfig(system_id=1, component_id=100, signing_key_file=str(key)), name="companion")
    link.start()
    downlink = Downlink(link, SurfaceConfig(budget_bytes_per_s=8000), dive=DIVE)
    downlink.start()
    try:
        yield downlink
    finally:
        downlink.stop()
        link.stop()


class Attacker:
    """Unsigned MAVLink 2 from a socket of its own, claiming whatever ids it likes."""

    def __init__(self, port: int) -> None:
        self.addr = ("127.0.0.1", port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0

    def send(self, msg, system: int = 1, component: int = 100) -> None:
        self.sock.sendto(msg.pack(mav.MAVLink(None, srcSystem=system, srcComponent=component)), self.addr)
        self.sent += 1
        time.sleep(0.002)

    def capture(self, index: int, depth_m: float, dive: str, system: int = 1) -> None:
        frame = summary_frame(index, depth=depth_m)
        self.send(captured_message(frame, 1000, dive=dive), system)

    def push(self, index: int) -> None:
        thumb = make_thumbnail(summary_frame(index).image)
        self.send(push_marker(index, 0))
        for msg in push_messages(thumb.data, thumb.width, thumb.height, 80):
            self.send(msg)


def test_an_unsigned_attacker_changes_nothing_the_signed_companion_owns(tmp_path):
    key = tmp_path / "signing.key"
    key.write_text("tether passphrase\n")
    port = free_udp_port()
    out = tmp_path / "gallery"
    attacker = Attacker(port)
    with surface_with_page(out, port, "--signing-key", str(key), "--push-timeout", "3", duration=90) as shown:
        web = shown.web
        # first the attacker, as another camera: a heartbeat and a capture would make it "the companion"
        for _ in range(5):
            attacker.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
                          system=42)
            attacker.capture(4242, 123.0, DIVE, system=42)
        with signed_companion(port, key) as companion:
            assert wait_until(lambda: page_state(web)["companion"]["id"] is not None, 15)
            frames = {i: summary_frame(i, depth=10.0 + i) for i in (5, 6, 7)}
            companion.publish(SummaryEvent("added", frames[5], summary=[5]))
            companion.publish(SummaryEvent("added", frames[6], summary=[5, 6]))

            def shows(indices: list[int]) -> bool:
                s = page_state(web)
                return [f["image_index"] for f in s["summary"]] == indices and all(
                    f["thumbnail"] for f in s["summary"])

            assert wait_until(lambda: shows([6, 5]), 30), page_state(web)
            # now as the companion itself: a fake capture with its picture, a fake trim, another dive
            attacker.capture(4242, 123.0, DIVE)
            attacker.push(4242)
            attacker.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO,
                                                         trimmed_text(frames[6], 1).encode()))
            attacker.capture(9, 50.0, "ffff0000")
            attacker.send(mav.MAVLink_named_value_float_message(0, b"MRL_DEPTH", 123.0))
            companion.publish(SummaryEvent("added", frames[7], summary=[5, 6, 7]))  # after the attack, in order
            assert wait_until(lambda: shows([7, 6, 5]), 30), page_state(web)
            state = page_state(web)
        shown.proc.terminate()
        last = shown.proc.stdout.read().strip().splitlines()[-1]
    assert f"{attacker.sent} unsigned messages ignored from 1/100, 42/100" in last, last
    assert state["companion"]["id"] == [1, 100]
    assert state["dive"] == DIVE
    assert 4242 not in [f["image_index"] for f in state["summary"]]
    assert all(f["depth_m"] < 100 for f in state["summary"])
    assert state["companion"]["values"].get("MRL_DEPTH") != 123.0
    assert state["link"]["unsigned_ignored"] == attacker.sent
    assert set(state["link"]["unsigned_sources"]) == {"42/100", "1/100"}
    assert any("unsigned" in w["text"] and "42/100" in w["text"] for w in state["companion"]["warnings"])
    gallery = json.loads((out / "gallery.json").read_text())
    assert "4242" not in json.dumps(gallery) and "ffff0000" not in json.dumps(gallery)
    assert not list(out.rglob("4242.*")) and not (out / "dives").exists()


def test_without_a_key_the_tool_still_takes_unsigned_companions(tmp_path):
    """No key: nothing to verify, so an unsigned companion is the companion (as before)."""
    port = free_udp_port()
    attacker = Attacker(port)
    with surface_with_page(tmp_path / "gallery", port, duration=60) as shown:
        attacker.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        assert wait_until(lambda: (attacker.capture(3, 12.0, DIVE), page_state(shown.web))[1]["summary"], 15)
        state = page_state(shown.web)
    assert state["companion"]["id"] == [1, 100] and state["link"]["unsigned_ignored"] == 0
