"""Issue 24 item 1 on real loopback sockets: a signing autopilot (1/1), a signed ground station and an unsigned
attacker sending autopilot HEARTBEATs from system 42 and ATTITUDE / GLOBAL_POSITION_INT claiming to be 1/1.

The companion learns its system id once, from the first autopilot, keeps it, and ignores (and counts) anything
unsigned that claims to be the autopilot once the autopilot was seen signing."""

from __future__ import annotations

import json
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from tests.conftest import free_udp_port, run_merlion
from tests.vehicle.tether import KEY, PASSPHRASE, Peer, Repeater, boot_ms, gcs_heartbeat, sub_heartbeat
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.autopilot.telemetry_watch import describe
from vehicle.camera.downlink import Downlink
from vehicle.camera.params import ParamSpec
from vehicle.link.connection import MavLink
from vehicle.settings import SurfaceConfig, TelemetryConfig

READS = 30


@pytest.fixture
def tether(tmp_path):
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file), component_id=100))
    telemetry = VehicleTelemetry(link, TelemetryConfig(stale_after_s=5.0), request_rates=False)
    telemetry.start()
    downlink = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000, push=False, status_hz=1),
                        params=[ParamSpec("MERL_K", 6, 1, 64, integer=True)])
    link.start()
    assert link.wait_open(5)
    downlink.start()
    peers: list[Peer] = []
    floods: list[Repeater] = []
    yield port, link, telemetry, peers, floods
    for f in floods:
        f.stop()
    downlink.stop()
    telemetry.stop()
    link.stop()
    for p in peers:
        p.close()


def _autopilot_stream(start: float):
    def make():
        t = boot_ms(start)
        return [sub_heartbeat(), mav2.MAVLink_attitude_message(t, 0.1, 0.0, 1.0, 0, 0, 0),
                mav2.MAVLink_global_position_int_message(t, 0, 0, 0, -12_000, 0, 0, 0, 65535)]
    return make


def _attacker_stream():
    fake = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)
    return lambda: [fake]


def _spoof_as_autopilot():
    return lambda: [mav2.MAVLink_attitude_message(0, 2.0, 2.0, 2.0, 0, 0, 0),
                    mav2.MAVLink_global_position_int_message(5, 0, 0, 0, -250_000, 0, 0, 0, 65535)]


def _signed_reads(port: int, peers: list[Peer], link: MavLink) -> tuple[int, int]:
    """READS signed PARAM_REQUEST_READs to 1/100, one at a time: how many got their PARAM_VALUE, and after how many
    the companion called itself another system than 1."""
    gcs = Peer(port, 255, 190, KEY)
    peers.append(gcs)
    gcs.send(gcs_heartbeat())
    answered = flipped = 0
    for _ in range(READS):
        before = len(gcs.got("PARAM_VALUE", (1, 100)))
        gcs.send(mav2.MAVLink_param_request_read_message(1, 100, b"MERL_K", -1))
        answered += wait_until(lambda b=before: len(gcs.got("PARAM_VALUE", (1, 100))) > b, 1.0)
        flipped += link.system_id != 1
    return answered, flipped


def test_a_strangers_heartbeats_and_spoofed_telemetry_change_nothing(tether):
    port, link, telemetry, peers, floods = tether
    start = time.monotonic()
    autopilot, attacker, impostor = Peer(port, 1, 1, KEY), Peer(port, 42, 1), Peer(port, 1, 1)
    peers += [autopilot, attacker, impostor]
    floods.append(Repeater(autopilot, _autopilot_stream(start), 10))
    assert link.wait_autopilot(5) and link.autopilot == (1, 1)
    assert wait_until(lambda: telemetry.latest.depth_m is not None, 5)
    floods.append(Repeater(attacker, _attacker_stream(), 20))
    floods.append(Repeater(impostor, _spoof_as_autopilot(), 20))
    impostor.send(sub_heartbeat())
    answered, flipped = _signed_reads(port, peers, link)
    print(f"\nsigned reads answered during the spoofed-heartbeat flood: {answered}/{READS}, "
          f"system id not 1 after {flipped}")
    assert (answered, flipped) == (READS, 0)
    assert link.autopilot == (1, 1) and link.system_id == 1
    assert link.foreign_autopilot_heartbeats > 0
    latest = telemetry.latest
    assert latest.depth_m == pytest.approx(12.0)  # never the impostor's 250 m
    assert telemetry.history.pose_at(boot_ms(start) / 1000.0).depth_m == pytest.approx(12.0)
    assert telemetry.boot_clock.reboots == 0  # ATTITUDE with time_boot_ms 0 did not "reboot" the autopilot
    # the impostor still floods and each of its messages is counted on the receive thread: read the three
    # reports again until no message was counted between the reads
    assert wait_until(lambda: telemetry.latest.spoofed_ignored == sum(link.signing.spoofed.values())
                      == link.stats()["signing"]["spoofed_autopilot"] > 0, 5)
    assert "claiming to be the autopilot ignored" in describe(latest)


def test_with_a_key_an_unsigned_autopilot_is_never_taken_and_the_signed_one_is(tether):
    """Issue 48: an unsigned autopilot heartbeat settles nothing (not even provisionally) when the companion has a
    key; the signed autopilot that comes after it is the autopilot, and strangers never move it."""
    port, link, telemetry, peers, floods = tether
    start = time.monotonic()
    attacker, autopilot = Peer(port, 42, 1), Peer(port, 1, 1, KEY)
    peers += [attacker, autopilot]
    for _ in range(5):
        attacker.send(sub_heartbeat())
    assert wait_until(lambda: link.signing.spoofed.get((42, 1), 0) == 5, 5)  # all five seen, none taken
    assert link.autopilot is None and link.system_id == 1 and not link.autopilot_alive
    floods.append(Repeater(autopilot, _autopilot_stream(start), 10))
    assert wait_until(lambda: link.autopilot == (1, 1), 5) and link.system_id == 1
    floods.append(Repeater(attacker, _attacker_stream(), 20))
    assert _signed_reads(port, peers, link) == (READS, 0)
    assert link.autopilot == (1, 1)


def test_with_unsigned_autopilot_allowed_a_first_unsigned_one_gives_way_to_the_signed_one(tmp_path):
    """The way out (mavlink.unsigned_autopilot) keeps the older rule: an unsigned first autopilot is provisional."""
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file), unsigned_autopilot=True))
    attacker, autopilot = Peer(port, 42, 1), Peer(port, 1, 1, KEY)
    link.start()
    try:
        assert link.wait_open(5)
        attacker.send(sub_heartbeat())
        assert wait_until(lambda: link.autopilot == (42, 1) and link.system_id == 42, 5)  # provisional
        autopilot.send(sub_heartbeat())  # the identity moves first, the system id right after it: wait for both
        assert wait_until(lambda: link.autopilot == (1, 1) and link.system_id == 1, 5)
        attacker.send(sub_heartbeat())
        assert wait_until(lambda: link.foreign_autopilot_heartbeats == 1, 5) and link.autopilot == (1, 1)
    finally:
        link.stop()
        attacker.close()
        autopilot.close()


def test_without_a_key_the_first_autopilot_is_kept(tmp_path):
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(component_id=100))
    link.start()
    first, second = Peer(port, 3, 1), Peer(port, 42, 1)
    try:
        assert link.wait_open(5)
        first.send(sub_heartbeat())
        assert link.wait_autopilot(5) and link.system_id == 3
        for _ in range(10):
            second.send(sub_heartbeat())
        assert wait_until(lambda: link.foreign_autopilot_heartbeats == 10, 5)
        assert link.autopilot == (3, 1) and link.system_id == 3
    finally:
        link.stop()
        first.close()
        second.close()


def test_merlion_telemetry_ignores_and_counts_the_impostor(tmp_path):
    """The real command, in its own process: a signed autopilot at 12 m, an unsigned impostor claiming 250 m."""
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    port = free_udp_port()
    start = time.monotonic()
    autopilot, impostor, stranger = Peer(port, 1, 1, KEY), Peer(port, 1, 1), Peer(port, 42, 1)
    floods = [Repeater(autopilot, _autopilot_stream(start), 10), Repeater(impostor, _spoof_as_autopilot(), 20),
              Repeater(stranger, _attacker_stream(), 20)]
    try:
        done = run_merlion("telemetry", "--connect", f"udpin:127.0.0.1:{port}", "--signing-key", str(key_file),
                           "--duration", "2", "--no-rates", "--json", timeout=120)
    finally:
        for f in floods:
            f.stop()
        for p in (autopilot, impostor, stranger):
            p.close()
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    latest, link = result["latest"], result["link"]
    assert latest["depth_m"] == pytest.approx(12.0) and latest["spoofed_ignored"] > 0
    assert link["autopilot"] == [1, 1] and link["system_id"] == 1 and link["foreign_autopilot_heartbeats"] > 0
    assert link["signing"]["spoofed_autopilot"] == latest["spoofed_ignored"]
    assert link["signing"]["autopilot"] == "signs with our key"
