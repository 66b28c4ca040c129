"""Signing on one link, with real UDP on loopback: keys, what is signed, what is refused, timestamps that persist."""

from __future__ import annotations

import hashlib
import socket
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from companion.errors import UsageError
from tests.conftest import free_udp_port, run_merlion
from tests.waiting import wait_until
from vehicle.link.connection import MavLink
from vehicle.link.signing import (
    RESERVE_AHEAD,
    LinkSigning,
    TimestampFile,
    is_state_changing,
    key_from_bytes,
    load_key,
    now_timestamp,
)
from vehicle.protocol.ftp import Op

KEY = hashlib.sha256(b"reef survey").digest()
OTHER = hashlib.sha256(b"not the key").digest()


class Station:
    """A ground station on a plain UDP socket that packs with its own pymavlink encoder (signed or not)."""

    def __init__(self, port: int, key: bytes | None, component: int = 190) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.addr = ("127.0.0.1", port)
        self.mav = mav2.MAVLink(None, srcSystem=255, srcComponent=component)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = now_timestamp()
        self.parser = mav2.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[mav2.MAVLink_message, bytes]] = []

    def send(self, msg: mav2.MAVLink_message) -> bytes:
        packet = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(packet, self.addr)
        return packet

    def pump(self) -> None:
        try:
            while True:
                data, _ = self.sock.recvfrom(4096)
                for m in self.parser.parse_buffer(data) or []:
                    self.received.append((m, bytes(m.get_msgbuf())))
        except (TimeoutError, BlockingIOError):
            pass

    def statustexts(self) -> list[str]:
        self.pump()
        return [m.text for m, _ in self.received if m.get_type() == "STATUSTEXT"]

    def close(self) -> None:
        self.sock.close()


def _param_set(value: float) -> mav2.MAVLink_message:
    return mav2.MAVLink_param_set_message(1, 100, b"MERL_K", value, mav2.MAV_PARAM_TYPE_REAL32)


@pytest.fixture
def signed_link(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("reef survey\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file)), heartbeat=False)
    seen: list = []
    link.subscribe(seen.append, ["PARAM_SET", "PARAM_REQUEST_LIST", "FILE_TRANSFER_PROTOCOL"])
    link.start()
    assert link.wait_open(5)
    yield link, port, seen
    link.stop()


def test_keys_are_raw_bytes_or_a_passphrase(tmp_path):
    raw = bytes(range(200, 232))
    assert key_from_bytes(raw) == raw
    assert key_from_bytes(b"reef survey\n") == KEY  # MAVProxy: sha256 of the passphrase
    (tmp_path / "empty").write_text("  \n")
    with pytest.raises(UsageError, match="empty"):
        load_key(tmp_path / "empty")
    with pytest.raises(UsageError, match="missing"):
        load_key(tmp_path / "missing")


def test_a_bad_key_file_is_a_one_line_error_when_the_link_is_made(tmp_path):
    with pytest.raises(UsageError, match="signing_key_file"):
        MavLink("udpin:127.0.0.1:9", MavlinkConfig(signing_key_file=str(tmp_path / "nope")))


def test_state_changing_messages_are_told_from_reads():
    ftp = mav2.MAVLink_file_transfer_protocol_message
    assert is_state_changing(_param_set(1))
    assert is_state_changing(mav2.MAVLink_command_long_message(1, 1, 511, 0, 30, 1e5, 0, 0, 0, 0, 0))
    assert is_state_changing(ftp(0, 1, 100, [0, 0, 0, Op.WRITE_FILE] + [0] * 247))
    assert not is_state_changing(ftp(0, 1, 100, [0, 0, 0, Op.READ_FILE] + [0] * 247))
    assert not is_state_changing(mav2.MAVLink_param_request_list_message(1, 100))
    assert not is_state_changing(mav2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))


def test_only_writes_signed_with_the_key_get_through_and_each_bad_source_warns_once(signed_link):
    link, port, seen = signed_link
    good, unsigned, wrong = Station(port, KEY, 190), Station(port, None, 191), Station(port, OTHER, 192)
    try:
        for station in (unsigned, wrong):
            for _ in range(5):
                station.send(_param_set(7))
            station.send(mav2.MAVLink_param_request_list_message(1, 100))  # reads pass unsigned (ArduPilot's rule)
        recorded = good.send(_param_set(3))
        assert wait_until(lambda: sum(m.get_type() == "PARAM_SET" for m in seen) == 1, 5)
        assert wait_until(lambda: sum(m.get_type() == "PARAM_REQUEST_LIST" for m in seen) == 2, 5)
        good.sock.sendto(recorded, good.addr)  # the same signed packet again: a replay
        good.send(mav2.MAVLink_param_request_list_message(1, 100))
        assert wait_until(lambda: sum(m.get_type() == "PARAM_REQUEST_LIST" for m in seen) == 3, 5)
        params = [m for m in seen if m.get_type() == "PARAM_SET"]
        assert [(p.get_srcComponent(), p.param_value) for p in params] == [(190, 3.0)]
        assert params[0]._signed
        stats = link.stats()["signing"]
        assert stats["rejected_by_source"] == {"255/191": 5, "255/192": 5, "255/190": 1}
        assert link.signing.reasons == {(255, 191): "unsigned", (255, 192): "bad signature", (255, 190): "replayed"}
        # one warning per refused source, to every peer the link knows (udpin: each client seen so far)
        stations = (good, unsigned, wrong)
        assert wait_until(lambda: len({t for s in stations for t in s.statustexts()}) >= 3, 5)
        wait_until(lambda: len({t for s in stations for t in s.statustexts()}) > 3, 0.3)  # a 4th would show by now
        assert {t.split(" from ")[1] for s in stations for t in s.statustexts()} == {
            "255/190 ignored", "255/191 ignored", "255/192 ignored"}
        for s in stations:
            assert len(s.statustexts()) == len(set(s.statustexts()))
    finally:
        for s in (good, unsigned, wrong):
            s.close()


def test_everything_the_link_sends_is_signed_with_rising_timestamps(signed_link):
    link, port, _ = signed_link
    station = Station(port, None)
    try:
        station.send(mav2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        assert wait_until(lambda: link.connected, 5)
        for i in range(20):
            link.send(mav2.MAVLink_named_value_float_message(i, b"x", float(i)))

        def got() -> int:
            station.pump()
            return len(station.received)

        assert wait_until(lambda: got() >= 20, 5)
        checker = LinkSigning(KEY, name="check")
        stamps = []
        for msg, raw in station.received:
            assert raw[2] & mav2.MAVLINK_IFLAG_SIGNED
            assert checker.admit(msg, lambda m: 0) and msg._signed  # valid with the key, not replayed
            stamps.append(int.from_bytes(raw[-12:-6], "little"))
        assert stamps == sorted(set(stamps))
    finally:
        station.close()


def test_unsigned_reads_can_be_refused_too(tmp_path):
    signing = LinkSigning(KEY, name="strict", accept_unsigned_reads=False)
    unsigned = mav2.MAVLink(None, 255, 190)
    parser = mav2.MAVLink(None)
    msg = parser.parse_buffer(mav2.MAVLink_param_request_list_message(1, 100).pack(unsigned))[0]
    warnings: list = []
    assert not signing.admit(msg, warnings.append)
    assert not signing.admit(msg, warnings.append)
    assert len(warnings) == 1 and signing.rejected == {(255, 190): 2}


def test_without_a_key_nothing_changes(tmp_path):
    signing = LinkSigning(None)
    tx = mav2.MAVLink(None, 1, 100)
    signing.prepare(tx)
    packet = _param_set(1).pack(tx)
    assert not packet[2] & mav2.MAVLINK_IFLAG_SIGNED
    assert signing.admit(mav2.MAVLink(None).parse_buffer(packet)[0], lambda m: 0)


def test_timestamps_are_reserved_ahead_so_a_restart_never_reuses_one(tmp_path):
    stamp_file = tmp_path / "ts"
    clock = [1_800_000_000.0]
    first = LinkSigning(KEY, timestamp_file=stamp_file, wall_clock=lambda: clock[0])
    tx = mav2.MAVLink(None, 1, 100)
    sent = []
    for _ in range(50):
        first.prepare(tx)
        sent.append(int.from_bytes(_param_set(1).pack(tx)[-12:-6], "little"))
    assert TimestampFile(stamp_file).load() >= max(sent)  # written before any of them went out
    assert TimestampFile(stamp_file).load() <= max(sent) + RESERVE_AHEAD
    clock[0] -= 3600  # even with the clock set back an hour (no RTC), the restarted link starts above
    second = LinkSigning(KEY, timestamp_file=stamp_file, wall_clock=lambda: clock[0])
    tx2 = mav2.MAVLink(None, 1, 100)
    second.prepare(tx2)
    assert int.from_bytes(_param_set(1).pack(tx2)[-12:-6], "little") > max(sent)


def test_the_receive_check_survives_a_parser_reset_and_concurrent_use(signed_link):
    """Stream timestamps live outside pymavlink's parser, which the link replaces after bad input."""
    link, port, seen = signed_link
    station = Station(port, KEY)
    try:
        recorded = station.send(_param_set(5))
        assert wait_until(lambda: len(seen) == 1, 5)
        station.sock.sendto(b"\xfd\x09garbage", station.addr)  # half a packet: the link starts a new parser
        threads = [threading.Thread(target=station.sock.sendto, args=(recorded, station.addr)) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        station.send(mav2.MAVLink_param_request_list_message(1, 100))
        assert wait_until(lambda: any(m.get_type() == "PARAM_REQUEST_LIST" for m in seen), 5)
        assert [m.get_type() for m in seen].count("PARAM_SET") == 1
    finally:
        station.close()


@pytest.mark.parametrize("command", [["run", "--mavlink", "udpin:127.0.0.1:9", "--duration", "1"],
                                     ["telemetry", "--connect", "udpin:127.0.0.1:9", "--duration", "1"],
                                     ["sim-vehicle", "--connect", "udpout:127.0.0.1:9", "--duration", "1"],
                                     ["surface", "--connect", "udpin:127.0.0.1:9", "--out", "GALLERY"]])
def test_a_bad_key_file_on_the_command_line_is_one_line_and_exit_2(tmp_path, command):
    (tmp_path / "empty.key").write_text("\n")
    command = [str(tmp_path / "gallery") if arg == "GALLERY" else arg for arg in command]
    done = run_merlion(*command, "--signing-key", str(tmp_path / "empty.key"), timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0] == f"merlion: error: mavlink.signing_key_file {tmp_path / 'empty.key'}: expected 32 raw bytes " \
                       "or a passphrase"
    assert not (tmp_path / "gallery").exists()  # nothing was made before the key was checked


def test_after_a_restart_old_recordings_are_stale_and_fresh_streams_welcome_even_without_a_clock(tmp_path):
    stamp_file = tmp_path / "ts"
    now = 1_800_000_000.0
    first = LinkSigning(KEY, timestamp_file=stamp_file, wall_clock=lambda: now)
    first.prepare(mav2.MAVLink(None, 1, 100))  # reserves a minute ahead
    gcs = mav2.MAVLink(None, 255, 190)
    gcs.signing.secret_key, gcs.signing.sign_outgoing = KEY, True
    parser = mav2.MAVLink(None)

    def recorded(at: float):
        gcs.signing.timestamp = now_timestamp(lambda: at)
        return parser.parse_buffer(_param_set(1).pack(gcs))[0]

    old, fresh = recorded(now - 600), recorded(now - 5)
    # restarted at boot with no RTC (the clock reads 1970): the reservation still says roughly when it is
    restarted = LinkSigning(KEY, timestamp_file=stamp_file, wall_clock=lambda: 0.0)
    assert not restarted.admit(old, lambda m: 0) and restarted.reasons[(255, 190)] == "stale signed"
    # with the clock right, a ground station a few seconds behind is a new stream, not stale
    assert LinkSigning(KEY, timestamp_file=stamp_file, wall_clock=lambda: now).admit(fresh, lambda m: 0)


def test_many_spoofed_sources_neither_flood_the_downlink_nor_grow_the_table():
    signing = LinkSigning(KEY, name="flood")
    parser = mav2.MAVLink(None)
    sent: list = []
    for i in range(2000):
        spoof = mav2.MAVLink(None, 1 + i % 250, 1 + i // 250)
        assert not signing.admit(parser.parse_buffer(_param_set(1).pack(spoof))[0], sent.append)
    assert len(sent) == 5 and signing.warnings_withheld > 0  # a burst of warnings, then counts only
    assert len(signing.rejected) <= 257 and sum(signing.rejected.values()) == 2000
