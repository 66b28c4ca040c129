"""Signing end to end with real processes on loopback: `merlion run` and the simulated ArduSub share one key, and
three ground stations (signed with the key, unsigned, signed with another key) try to change the companion."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Companion, Listener, reap_companions, wait_until, write_config
from vehicle.link.signing import LinkSigning, TimestampFile, now_timestamp
from vehicle.protocol.ftp import FtpPacket, Op
from vehicle.sim.vehicle import SimVehicle

PASSPHRASE = "reef survey 17"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()
OTHER = hashlib.sha256(b"someone else's key").digest()
COMPANION = (1, 100)


class Station(Listener):
    """A ground station on the hub: hears everything, packs with its own encoder (signed with ``key`` or not)."""

    def __init__(self, hub: UdpHub, component: int, key: bytes | None) -> None:
        super().__init__()
        self.hub = (hub.host, hub.port)
        self.mav = mav2.MAVLink(None, srcSystem=255, srcComponent=component)
        if key is not None:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = key, True
            self.mav.signing.timestamp = now_timestamp()
        self.component = component
        self.ftp_seq = 0

    def send(self, msg: mav2.MAVLink_message) -> bytes:
        packet = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(packet, self.hub)
        return packet

    def set_k(self, value: float) -> bytes:
        return self.send(mav2.MAVLink_param_set_message(*COMPANION, b"MERL_K", value, mav2.MAV_PARAM_TYPE_INT32))

    def ftp(self, op: int, *, session: int = 0, offset: int = 0, data: bytes = b"") -> None:
        self.ftp_seq += 1
        payload = FtpPacket(self.ftp_seq, session, op, offset=offset, data=data).pack()
        self.send(mav2.MAVLink_file_transfer_protocol_message(0, *COMPANION, payload))

    def ftp_reply(self, seq: int) -> FtpPacket:
        def mine(m) -> bool:
            return (m.get_type() == "FILE_TRANSFER_PROTOCOL" and m.target_component == self.component
                    and FtpPacket.unpack(m.payload).seq == seq + 1)
        return FtpPacket.unpack(self.wait_for(mine, 20, "FTP reply").payload)

    def upload_queries(self, text: bytes, wait: bool) -> None:
        """CreateFile, WriteFile, TerminateSession of /config/queries.txt (waiting for each ACK when ``wait``)."""
        self.ftp(Op.CREATE_FILE, data=b"/config/queries.txt")
        session = self.ftp_reply(self.ftp_seq).session if wait else 0
        self.ftp(Op.WRITE_FILE, session=session, data=text)
        if wait:
            assert self.ftp_reply(self.ftp_seq).opcode == Op.ACK
        self.ftp(Op.TERMINATE_SESSION, session=session)
        if wait:
            assert self.ftp_reply(self.ftp_seq).opcode == Op.ACK

    def from_companion(self) -> list:
        with self._cond:
            return [m for m in self.messages if (m.get_srcSystem(), m.get_srcComponent()) == COMPANION]

    def warnings(self) -> list[str]:
        return [t for t in self.texts() if "ignored" in t]


def _stamp(msg) -> int:
    return int.from_bytes(bytes(msg.get_msgbuf())[-12:-6], "little")


def _join(hub: UdpHub, stations: list[Station], component: int, key: bytes | None) -> Station:
    """A ground station on the hub that has sent its GCS heartbeat; the ``setup`` fixture closes it."""
    station = Station(hub, component, key)
    stations.append(station)
    station.send(mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3))
    return station


def _signed_companion(cfg: Path, key_file: Path) -> Companion:
    """`merlion run` with the shared key, once it hears the (signing) autopilot's heartbeat."""
    companion = Companion("--config", str(cfg), "--signing-key", str(key_file))
    companion.wait_for("autopilot heartbeat up")
    return companion


@pytest.fixture
def setup(tmp_path: Path):
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    hub = UdpHub().start()
    sim = SimVehicle(hub.url, rates={"HEARTBEAT": 2.0}, signing_key_file=str(key_file))
    sim.start()
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       surface={"ftp_writable": True, "budget_bytes_per_s": 20000, "status_hz": 2})
    stations: list[Station] = []
    yield key_file, hub, sim, store, cfg, stations
    reap_companions()
    for s in stations:
        s.close()
    sim.stop()
    hub.stop()


def test_only_the_signed_station_changes_the_companion(setup) -> None:
    key_file, hub, sim, store, cfg, stations = setup
    companion = Companion("--config", str(cfg), "--signing-key", str(key_file))
    companion.wait_for("companion running")
    good, unsigned, wrong = (_join(hub, stations, c, k) for c, k in ((190, KEY), (191, None), (192, OTHER)))
    companion.wait_for("autopilot heartbeat up")

    # the companion's own rate requests reach the signed autopilot only because they are signed
    wait_until(lambda: any(c[0] == mav2.MAV_CMD_SET_MESSAGE_INTERVAL and c[3] == mav2.MAV_RESULT_ACCEPTED
                           for c in sim.commands), 30, "an accepted SET_MESSAGE_INTERVAL")
    assert COMPANION not in sim.link.signing.rejected  # (the unsigned and wrong-key stations' heartbeats are)

    for bad in (unsigned, wrong):
        for value in (41, 42, 43):
            bad.set_k(value)
        bad.upload_queries(b"a diver\n", wait=False)
    recorded = good.set_k(7)
    companion.wait_for(r"parameter MERL_K set to 7\b", 30)
    good.set_k(8)
    companion.wait_for(r"parameter MERL_K set to 8\b", 30)
    good.sock.sendto(recorded, good.hub)  # the recorded signed PARAM_SET again, later: a replay
    good.upload_queries(b"a coral reef\nsand\n", wait=True)
    companion.wait_for("queries set: 'a coral reef'", 30)
    good.send(mav2.MAVLink_param_request_read_message(*COMPANION, b"MERL_K", -1))
    good.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MERL_K" and m.param_value == 8
                  and (m.get_srcSystem(), m.get_srcComponent()) == COMPANION, 20, "MERL_K still 8")
    assert "set to 4" not in companion.output and "set to 7" in companion.output
    assert "a diver" not in companion.output

    # one warning each for the unsigned station, the wrong key and the replay (however many packets they sent)
    wait_until(lambda: len({w for w in good.warnings()}) >= 3, 20, "three signing warnings")
    warnings = good.warnings()
    assert sorted(w.split(" from ")[1] for w in warnings) == ["255/190 ignored", "255/191 ignored",
                                                              "255/192 ignored"], warnings
    assert any(w.startswith("replayed PARAM_SET") for w in warnings)

    # telemetry and tagging work as without signing
    wait_until(lambda: any(json.loads(p.read_text())["pose"]["depth_m"] is not None
                           for p in (store / "frames").glob("*.json")), 60, "a frame tagged with depth")
    assert companion.terminate() == 0, companion.output
    assert "signing on; refused" in companion.output and "'255/191': " in companion.output  # the counts show

    # every message the companion sent is signed with the key, with timestamps that only go up
    sent = good.from_companion()
    assert len(sent) > 20
    checker = LinkSigning(KEY, name="check")
    assert all(checker.admit(m, lambda _m: 0) for m in sent)
    stamps = [_stamp(m) for m in sent]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


def test_a_restarted_companion_signs_above_everything_it_sent_before(setup) -> None:
    key_file, hub, sim, store, cfg, stations = setup
    listener = _join(hub, stations, 190, None)
    first = _signed_companion(cfg, key_file)
    wait_until(lambda: len(listener.from_companion()) >= 10, 30, "ten messages from the companion")
    first.kill()  # no clean shutdown: the timestamps were reserved on disk before they were used
    reserved = TimestampFile(key_file.parent / "signing.key.comp100.timestamp").load()
    assert max(_stamp(m) for m in listener.from_companion()) < reserved  # on disk before any of them went out
    # a station that joins the hub now hears nothing of the first process: the hub forwards in arrival order,
    # and all the first process sent was queued before this heartbeat
    newcomer = _join(hub, stations, 193, None)
    newcomer.wait_for(lambda m: m.get_type() == "HEARTBEAT", 10, "the hub forwarding to the newcomer")
    assert newcomer.from_companion() == []
    second = Companion("--config", str(cfg), "--signing-key", str(key_file))
    wait_until(lambda: newcomer.from_companion(), 60, "a message from the restarted companion")
    assert _stamp(newcomer.from_companion()[0]) >= reserved  # above every timestamp the first process used
    assert second.terminate() == 0, second.output


def test_a_signed_write_recorded_before_a_sigkill_is_a_replay_after_the_restart(setup) -> None:
    """Issue 24 item 5: the timestamps seen from others persist like our own (in the same state file)."""
    key_file, hub, sim, store, cfg, stations = setup
    good = _join(hub, stations, 190, KEY)
    first = _signed_companion(cfg, key_file)
    recorded = good.set_k(7)
    first.wait_for(r"parameter MERL_K set to 7\b", 30)
    good.set_k(8)
    good.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MERL_K" and m.param_value == 8, 20,
                  "MERL_K 8 saved and echoed")
    first.kill()  # SIGKILL: no clean shutdown, nothing written on the way out
    streams = TimestampFile(key_file.parent / "signing.key.comp100.timestamp").load_streams()
    assert streams[(0, 255, 190)] >= _stamp(mav2.MAVLink(None).parse_buffer(recorded)[0])
    second = _signed_companion(cfg, key_file)
    good.sock.sendto(recorded, good.hub)  # the recording, seconds after it was made: well inside a new stream's minute
    wait_until(lambda: any(w.startswith("replayed PARAM_SET from 255/190") for w in good.warnings()), 30,
               "the replay refused")
    good.set_k(9)  # the real station goes on signing above what it sent before
    second.wait_for(r"parameter MERL_K set to 9\b", 30)
    assert "set to 7" not in second.output, second.output
    assert second.terminate() == 0, second.output


@pytest.mark.slow
def test_an_unsigned_companion_beside_a_signing_autopilot_says_so_and_blames_nobody_else(setup) -> None:
    """Issue 24 item 8: the simulated ArduSub signs and drops everything unsigned; the companion has no key."""
    key_file, hub, sim, store, cfg, stations = setup
    # asked again after 1 s, then 2 and 4, instead of 3, 6 and 12: the three unanswered asks come sooner
    cfg = write_config(cfg.parent / "fast-asks.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       telemetry={"rate_grace_s": 1.0})
    station = _join(hub, stations, 190, None)  # the router carries the companion's word past the autopilot
    companion = Companion("--config", str(cfg))
    companion.wait_for("the autopilot signs its messages and this companion has no signing key", 30)
    wait_until(lambda: "Autopilot signs: it ignores us (no key)" in station.texts(), 30, "the STATUSTEXT")
    companion.wait_for("LOCAL_POSITION_NED never came: the autopilot signs, and this companion has no key", 60)
    assert "no DVL or USBL" not in companion.output and "never sends" not in companion.output
    assert companion.terminate() == 0, companion.output
    assert "merlion run: the autopilot signs, and this companion has no key" in companion.output
    assert station.texts().count("Autopilot signs: it ignores us (no key)") == 1  # said once


def test_manual_control_for_the_autopilot_is_never_refused_as_ours(setup) -> None:
    key_file, hub, sim, store, cfg, stations = setup
    companion = _signed_companion(cfg, key_file)
    good, joystick = _join(hub, stations, 190, KEY), _join(hub, stations, 191, None)
    for _ in range(20):  # an unsigned ground station's joystick, for the vehicle (target: system 1)
        joystick.send(mav2.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))
        joystick.send(mav2.MAVLink_rc_channels_override_message(1, 1, *([1500] * 8)))
    joystick.set_k(40)  # an unsigned write that *is* for the companion is still refused and reported

    def ours() -> list[str]:  # the companion's warnings (the simulated autopilot reports what it refuses itself)
        return [m.text for m in good.from_companion() if m.get_type() == "STATUSTEXT" and "ignored" in m.text]

    wait_until(lambda: any("PARAM_SET from 255/191" in w for w in ours()), 30, "the PARAM_SET refusal")
    assert companion.terminate() == 0, companion.output
    assert not any("MANUAL_CONTROL" in w or "RC_CHANNELS" in w for w in ours()), ours()
    assert "MANUAL_CONTROL" not in companion.output and "RC_CHANNELS_OVERRIDE" not in companion.output
