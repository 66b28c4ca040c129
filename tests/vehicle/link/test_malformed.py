"""Garbage on the wire: random bytes, truncated and corrupted packets are counted and logged (at most once per
10 s, so a flood cannot fill the disk), never a crash."""

from __future__ import annotations

import logging
import random
import socket
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from tests.conftest import free_tcp_port, free_udp_port
from vehicle.link.connection import MavLink

FAST = {"heartbeat_timeout_s": 2.0, "reconnect_initial_s": 0.05, "reconnect_max_s": 0.2}


def _heartbeat(seq: int = 0) -> bytes:
    packer = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    packer.seq = seq
    return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4,
                                          3).pack(packer)


def _statustext(text: bytes) -> bytes:
    return mav2.MAVLink_statustext_message(6, text).pack(mav2.MAVLink(None, srcSystem=1, srcComponent=1))


def _garbage(rng: random.Random) -> list[bytes]:
    good = _heartbeat()
    corrupt = bytearray(good)
    corrupt[12] ^= 0xFF  # payload byte changed: the CRC no longer matches
    chunks = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 280))) for _ in range(60)]
    chunks += [good[:7], good[:15], bytes(corrupt), b"\xfd", b"\xfe\xff" * 50, bytes(300)]
    rng.shuffle(chunks)
    return chunks


def test_udp_garbage_is_counted_and_the_link_keeps_working(caplog):
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST))
    texts: list = []
    done = threading.Event()
    link.subscribe(lambda m: (texts.append(m), m.text == "after" and done.set()), ["STATUSTEXT"])
    link.start()
    assert link.wait_open(5)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with caplog.at_level(logging.WARNING, logger="vehicle.link.connection"):
            for seed in range(7, 12):  # hundreds of bad packets in well under the log's 10 s
                for chunk in _garbage(random.Random(seed)):
                    sender.sendto(chunk, ("127.0.0.1", port))
            # a truncated packet may swallow the start of the next datagram: send the good ones twice
            for _ in range(2):
                sender.sendto(_heartbeat(), ("127.0.0.1", port))
                sender.sendto(_statustext(b"after"), ("127.0.0.1", port))
            assert done.wait(5), "a good packet after the garbage never arrived"
        assert link.wait_autopilot(5)
        assert link.rx_bad >= 100  # the corrupted CRCs, the truncated packets, the random bytes
        assert link.rx_bytes > 0 and all(t.text == "after" for t in texts)
        said = [r for r in caplog.records if "bad MAVLink input" in r.getMessage()]
        assert len(said) == 1, "bad input is logged at most once per BAD_LOG_S, whatever the flood's rate"
        assert link.send(mav2.MAVLink_statustext_message(6, b"still here")) > 0
    finally:
        sender.close()
        link.stop()


def test_tcp_stream_resynchronises_after_garbage():
    port = free_tcp_port()
    link = MavLink(f"tcpin:127.0.0.1:{port}", MavlinkConfig(**FAST))
    got = threading.Event()
    link.subscribe(lambda m: got.set(), ["STATUSTEXT"])
    link.start()
    assert link.wait_open(5)
    rng = random.Random(11)
    stream = b"".join(_garbage(rng)) + _statustext(b"one") + b"\x00" * 40 + _statustext(b"two")
    with socket.create_connection(("127.0.0.1", port), timeout=5) as client:
        client.sendall(stream)
        assert got.wait(5)
        client.sendall(_heartbeat())
        assert link.wait_autopilot(5)
    assert link.rx_bad >= 1
    link.stop()


@pytest.mark.parametrize("cut", [1, 5, 11, 20])
def test_a_truncated_packet_alone_is_not_a_message(cut):
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST))
    seen: list = []
    got = threading.Event()
    link.subscribe(seen.append)
    link.subscribe(lambda m: got.set(), ["STATUSTEXT"])
    link.start()
    assert link.wait_open(5)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(_heartbeat()[:cut], ("127.0.0.1", port))
        # then full packets, whose bytes complete or reveal the broken one
        for _ in range(3):
            s.sendto(_statustext(b"x"), ("127.0.0.1", port))
        assert got.wait(5)
    link.stop()
    assert link.autopilot is None  # the half heartbeat never counted as one
    assert all(m.get_type() == "STATUSTEXT" for m in seen)
