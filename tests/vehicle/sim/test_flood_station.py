"""The flood benches' signed ground station hears every signed capture sent right after a garbage datagram (behind a
router the flood's garbage reaches it too): pymavlink's own reader, which parses UDP as one byte stream, lost most
of them, and so did the live bench's figures (~10% of the captures)."""

from __future__ import annotations

import random
import socket
import threading

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.link.signing import key_from_bytes
from vehicle.sim.flood_bench import SignedStation

KEY = key_from_bytes(b"reef survey\n")
CAPTURES = 50


def _capture(packer: mav2.MAVLink, index: int) -> bytes:
    msg = mav2.MAVLink_camera_image_captured_message(0, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0], index, 1, b"")
    packet = msg.pack(packer)
    packer.seq = (packer.seq + 1) % 256
    return packet


def test_each_signed_capture_after_a_garbage_datagram_is_heard_and_unsigned_ones_are_not():
    rng = random.Random(3)
    companion = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    companion.bind(("127.0.0.1", free_udp_port()))
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{companion.getsockname()[1]}", source_system=255,
                                     source_component=190, dialect="ardupilotmega")
    gcs.setup_signing(KEY, sign_outgoing=True)
    station = SignedStation(gcs)
    listener = threading.Thread(target=station.run, daemon=True)
    signed = mav2.MAVLink(None, srcSystem=1, srcComponent=100)
    signed.signing.secret_key, signed.signing.sign_outgoing, signed.signing.timestamp = KEY, True, 1
    unsigned = mav2.MAVLink(None, srcSystem=1, srcComponent=100)
    try:
        gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        _, station_addr = companion.recvfrom(512)  # where the station listens (its first datagram says)
        listener.start()
        for index in range(1, CAPTURES + 1):  # as the flood sends it: a packet's start byte and length, then noise
            companion.sendto(bytes([0xFD, rng.randrange(1, 255)]) + rng.randbytes(rng.randrange(4, 60)), station_addr)
            companion.sendto(_capture(signed, index), station_addr)
        companion.sendto(_capture(unsigned, 1000), station_addr)
        companion.sendto(_capture(signed, CAPTURES + 1), station_addr)
        assert wait_until(lambda: CAPTURES + 1 in station.captures, 20)
        assert sorted(station.captures) == list(range(1, CAPTURES + 2))  # all signed ones, not the unsigned one
        assert station.truncated > 0
    finally:
        station.stop.set()
        listener.join(5)
        gcs.close()
        companion.close()
