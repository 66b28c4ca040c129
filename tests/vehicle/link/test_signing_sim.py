"""The simulated ArduSub with a key: the companion's rate requests are obeyed only because it signs them."""

from __future__ import annotations

import hashlib
import socket

from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import FAST_LINK, quick_dive
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.link.signing import now_timestamp
from vehicle.sim.vehicle import SimVehicle

SET_MESSAGE_INTERVAL = mav2.MAV_CMD_SET_MESSAGE_INTERVAL


def _run(tmp_path, *, companion_signs: bool):
    key_file = tmp_path / "key"
    key_file.write_text("reef survey\n")
    port = free_udp_port()
    cfg = MavlinkConfig(**FAST_LINK, signing_key_file=str(key_file) if companion_signs else None)
    link = MavLink(f"udpin:127.0.0.1:{port}", cfg)
    tel = VehicleTelemetry(link, TelemetryConfig(attitude_hz=25.0, stale_after_s=0.4))
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=str(key_file))
    tel.start()
    link.start()
    sim.start()
    return link, tel, sim


def test_a_signed_sim_obeys_the_companion_because_it_signs(tmp_path):
    link, tel, sim = _run(tmp_path, companion_signs=True)
    try:
        assert wait_until(lambda: any(c[0] == SET_MESSAGE_INTERVAL for c in sim.commands), 10)
        assert wait_until(lambda: tel.latest.depth_m is not None, 10)
        assert sim.interval("ATTITUDE") == 1 / 25.0 or abs(sim.interval("ATTITUDE") - 0.04) < 1e-6
        assert link.signing.accepted_signed > 0  # what the sim sends is signed with the key
        assert sim.link.stats()["signing"]["rejected"] == 0
    finally:
        sim.stop()
        tel.stop()
        link.stop()


def test_a_signed_sim_ignores_an_unsigned_companion_but_telemetry_still_flows(tmp_path):
    link, tel, sim = _run(tmp_path, companion_signs=False)
    try:
        assert wait_until(lambda: sim.link.signing.rejected.get((1, 100), 0) >= 1, 10)
        assert wait_until(lambda: tel.latest.depth_m is not None, 10)
        assert sim.commands == []
        assert sim.interval("ATTITUDE") != 1 / 25.0
    finally:
        sim.stop()
        tel.stop()
        link.stop()


def test_setup_signing_from_a_ground_station_turns_signing_on(tmp_path):
    key = hashlib.sha256(b"set by the gcs").digest()
    port = free_udp_port()
    sim = SimVehicle(f"udpin:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0})
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    plain = mav2.MAVLink(None, 255, 190)
    signed = mav2.MAVLink(None, 255, 190)
    signed.signing.secret_key, signed.signing.sign_outgoing = key, True
    signed.signing.timestamp = now_timestamp()
    arm = mav2.MAVLink_command_long_message(1, 1, SET_MESSAGE_INTERVAL, 0, 30, 50_000, 0, 0, 0, 0, 0)
    sim.start()
    try:
        assert sim.link.wait_open(5)
        gcs.sendto(mav2.MAVLink_setup_signing_message(1, 1, list(key), now_timestamp()).pack(plain),
                   ("127.0.0.1", port))
        assert wait_until(lambda: sim.link.signing.enabled, 5)
        gcs.sendto(arm.pack(plain), ("127.0.0.1", port))  # unsigned: ignored now
        gcs.sendto(arm.pack(signed), ("127.0.0.1", port))
        assert wait_until(lambda: len(sim.commands) == 1, 5)
        assert sim.link.signing.rejected == {(255, 190): 1}
        # the command is recorded before its ACK is sent: wait for the ACK (not 50 ms), and judge what the sim sends
        # from its first signed packet on (one sent while SETUP_SIGNING was being handled may predate the key)
        gcs.settimeout(5)
        heard = _until_ack(gcs, SET_MESSAGE_INTERVAL)
        flags = [bool(m.get_msgbuf()[2] & mav2.MAVLINK_IFLAG_SIGNED) for m in heard]
        assert flags[-1] and all(flags[flags.index(True):])  # and what the sim sends is signed
    finally:
        gcs.close()
        sim.stop()


def _until_ack(gcs: socket.socket, command: int) -> list[mav2.MAVLink_message]:
    """Everything the sim sent to ``gcs`` up to and including the COMMAND_ACK of ``command``."""
    parser = mav2.MAVLink(None)
    heard: list[mav2.MAVLink_message] = []
    while not any(m.get_type() == "COMMAND_ACK" and m.command == command for m in heard):
        data, _ = gcs.recvfrom(4096)
        heard.extend(parser.parse_buffer(data) or [])
    return heard


def test_a_signed_sim_drops_unsigned_packets_silently_as_ardusub_does(tmp_path):
    """ArduSub with a key drops every unsigned packet on SERIAL1+ (heartbeats and MANUAL_CONTROL too) and says
    nothing: no refusal STATUSTEXT, no ACK, no parameter. The unsigned packets go first; the signed request after them is
    answered, so by its ACK anything the sim had to say about them would have arrived (one sender, one order)."""
    key_file = tmp_path / "key"
    key_file.write_text("reef survey\n")
    port = free_udp_port()
    sim = SimVehicle(f"udpin:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=str(key_file))
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(5)
    plain = mav2.MAVLink(None, 255, 190)
    signed = mav2.MAVLink(None, 255, 190)
    signed.signing.secret_key = hashlib.sha256(b"reef survey").digest()
    signed.signing.sign_outgoing, signed.signing.timestamp = True, now_timestamp()
    unsigned = [
        mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
        mav2.MAVLink_command_long_message(1, 1, SET_MESSAGE_INTERVAL, 0, 30, 50_000, 0, 0, 0, 0, 0),
        mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0),
        mav2.MAVLink_request_data_stream_message(1, 1, mav2.MAV_DATA_STREAM_ALL, 50, 1),
        mav2.MAVLink_param_request_list_message(1, 1),
        mav2.MAVLink_param_set_message(1, 1, b"FS_GCS_ENABLE", 0, mav2.MAV_PARAM_TYPE_INT8),
    ]
    sim.start()
    try:
        assert sim.link.wait_open(5)
        for msg in unsigned:
            gcs.sendto(msg.pack(plain), ("127.0.0.1", port))
        ask = mav2.MAVLink_command_long_message(1, 1, mav2.MAV_CMD_GET_MESSAGE_INTERVAL, 0, 30, 0, 0, 0, 0, 0, 0)
        gcs.sendto(ask.pack(signed), ("127.0.0.1", port))
        heard = _until_ack(gcs, mav2.MAV_CMD_GET_MESSAGE_INTERVAL)
        assert [m.get_type() for m in heard if m.get_type() in ("STATUSTEXT", "PARAM_VALUE")] == []
        assert [m.command for m in heard if m.get_type() == "COMMAND_ACK"] == [mav2.MAV_CMD_GET_MESSAGE_INTERVAL]
        assert [c[0] for c in sim.commands] == [mav2.MAV_CMD_GET_MESSAGE_INTERVAL]
        assert sim.heartbeat_senders == set() and sim.manual_control_senders == set()
        assert sim.data_stream_requests == [] and sim.interval("ATTITUDE") == 0.1
        assert sim.params.sets == [] and sim.params.value("FS_GCS_ENABLE") == 2
        assert sum(sim.link.signing.rejected.values()) == len(unsigned)  # counted on board, never announced
    finally:
        gcs.close()
        sim.stop()


def test_a_signed_sim_on_serial0_still_obeys_unsigned_packets_and_signs_its_answers(tmp_path):
    """ArduPilot's channel 0 (SERIAL0, USB) is trusted: with a key it still acts on unsigned packets
    (accept_unsigned_callback in libraries/GCS_MAVLink/GCS_Signing.cpp), while what it sends is signed."""
    key_file = tmp_path / "key"
    key_file.write_text("reef survey\n")
    port = free_udp_port()
    sim = SimVehicle(f"udpin:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=str(key_file))
    sim.link.signing.trust_unsigned = True
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(5)
    plain = mav2.MAVLink(None, 255, 190)
    sim.start()
    try:
        assert sim.link.wait_open(5)
        ask = mav2.MAVLink_command_long_message(1, 1, SET_MESSAGE_INTERVAL, 0, 30, 50_000, 0, 0, 0, 0, 0)
        gcs.sendto(ask.pack(plain), ("127.0.0.1", port))
        heard = _until_ack(gcs, SET_MESSAGE_INTERVAL)
        assert [c[0] for c in sim.commands] == [SET_MESSAGE_INTERVAL] and sim.link.signing.rejected == {}
        assert heard[-1].get_msgbuf()[2] & mav2.MAVLINK_IFLAG_SIGNED  # the ACK is signed
    finally:
        gcs.close()
        sim.stop()
