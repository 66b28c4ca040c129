"""The ground-station listener on real loopback UDP: what it keeps, when it got it, and that the soak benchmark
and the live tests use this one implementation."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.bench import soak_bench
from tests.companion import live_harness
from vehicle.sim.ground_listener import GroundListener


def _captured(index: int, time_utc_s: float) -> mav.MAVLink_message:
    return mav.MAVLink_camera_image_captured_message(0, int(time_utc_s * 1e6), 1, 0, 0, 0, 0, [1, 0, 0, 0], index, 1,
                                                     b"")


def test_the_listener_keeps_what_it_is_asked_for_stamped_on_arrival() -> None:
    everything, captures = GroundListener(), GroundListener(types=["CAMERA_IMAGE_CAPTURED"])
    packer = mav.MAVLink(None, srcSystem=1, srcComponent=100)
    sent_at = time.time()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for listener in (everything, captures):
            for msg in (mav.MAVLink_statustext_message(6, b"hello"), _captured(7, sent_at - 0.5)):
                sock.sendto(msg.pack(packer), ("127.0.0.1", listener.port))
            sock.sendto(b"\xfd garbage", ("127.0.0.1", listener.port))
    try:
        everything.wait_for(lambda m: m.get_type() == "CAMERA_IMAGE_CAPTURED", 5, "capture")
        captures.wait_for(lambda m: m.get_type() == "CAMERA_IMAGE_CAPTURED", 5, "capture")
        assert everything.texts() == ["hello"] and [m.get_type() for m in captures.messages] == ["CAMERA_IMAGE_CAPTURED"]
        got = captures.messages[0]
        assert sent_at <= got.received_at <= time.time() and got.image_index == 7
        with pytest.raises(AssertionError, match="no reply within 0.2 s"):
            captures.wait_for(lambda m: m.get_type() == "STATUSTEXT", 0.2, "reply")
    finally:
        everything.close()
        captures.close()


def test_soak_latencies_count_each_capture_once_from_its_first_arrival() -> None:
    first, again, other = _captured(1, 100.0), _captured(1, 100.0), _captured(2, 101.0)
    first.received_at, again.received_at, other.received_at = 100.25, 103.0, 101.5
    assert soak_bench.capture_latencies([first, again, other]) == [0.25, 0.5]


def test_one_listener_serves_the_soak_benchmark_and_the_live_tests() -> None:
    assert live_harness.Listener is GroundListener is soak_bench.GroundListener
    assert not hasattr(soak_bench, "_Surface")
