"""Log replay: the real ArduSub tlog read like pymavlink reads it, timing kept, bad records skipped, and the
companion's telemetry showing the log's depth and attitude after a fast replay through the CLI."""

from __future__ import annotations

import collections
import itertools
import json
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import REPO, free_udp_port, run_merlion, shared_file
from tests.vehicle.sim_env import FAST_LINK
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.replay import TlogReplay, TlogStats, read_tlog

LOG = "ardusub/surface_small.tlog"


def _packet(msg: mav2.MAVLink_message, system: int = 1, component: int = 1) -> bytes:
    return msg.pack(mav2.MAVLink(None, srcSystem=system, srcComponent=component))


def _record(t_us: int, packet: bytes) -> bytes:
    return struct.pack(">Q", t_us) + packet


def _synthetic_log(path, times_s=(0.0, 0.5, 1.5, 1.5, 3.0)) -> list[bytes]:
    """Attitude packets at the given times (from an epoch start), one corrupted record and junk between."""
    t0 = 1_700_000_000_000_000
    packets = [_packet(mav2.MAVLink_attitude_message(int(t * 1000), 0.01 * i, 0.0, 0.0, 0, 0, 0))
               for i, t in enumerate(times_s)]
    bad = bytearray(_packet(mav2.MAVLink_attitude_message(9, 9.0, 9.0, 9.0, 0, 0, 0)))
    bad[15] ^= 0x55
    body = _record(t0, packets[0]) + _record(t0 + 100_000, bytes(bad)) + _record(t0 + int(times_s[1] * 1e6), packets[1])
    body += b"\x13\x37junk"
    for t, p in zip(times_s[2:], packets[2:], strict=True):
        body += _record(t0 + int(t * 1e6), p)
    path.write_bytes(body)
    return packets


def test_reader_agrees_with_pymavlink_on_the_real_log():
    path = shared_file(LOG)
    n = 12_000  # the first ~70 s of the log hold all its bad frames; the whole log would take twice as long
    ours = TlogStats()
    our_types = [r.msg_type for r in itertools.islice(read_tlog(path, ours), n)]
    their_types: list[str] = []
    bad = 0
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    while len(their_types) < n and (msg := log.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA":
            bad += 1
        else:
            their_types.append(msg.get_type())
    assert our_types == their_types
    assert ours.bad_crc == bad > 0  # the README says the log has some bad-CRC frames
    counts = collections.Counter(our_types)
    assert counts["ATTITUDE"] > 1000 and counts["SCALED_PRESSURE2"] > 100


def test_synthetic_log_skips_bad_records_and_keeps_timing(tmp_path):
    path = tmp_path / "dive.tlog"
    packets = _synthetic_log(path)
    stats = TlogStats()
    records = list(read_tlog(path, stats))
    assert [r.packet for r in records] == packets
    assert stats.bad_crc == 1 and stats.resync_bytes == 6

    port = free_udp_port()
    rx = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK), heartbeat=False, name="rx")
    got: list = []
    all_in = threading.Event()
    rx.subscribe(lambda m: (got.append(m), len(got) == len(packets) and all_in.set()), ["ATTITUDE"])
    rx.start()
    tx = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=1), heartbeat=False)
    tx.start()
    assert rx.wait_open(5) and tx.wait_open(5)
    now = [0.0]
    sent_at: list[float] = []

    def virtual_wait(seconds: float) -> bool:  # a virtual clock: no real sleeping, exact due times
        now[0] += seconds
        return False

    original = tx.send_raw
    tx.send_raw = lambda packet: (sent_at.append(now[0]), original(packet))[1]
    replay = TlogReplay(path, tx, speed=2.0, clock=lambda: now[0], wait=virtual_wait)
    stats = replay.run()
    try:
        assert all_in.wait(5)
    finally:
        tx.stop()
        rx.stop()
    assert sent_at == pytest.approx([0.0, 0.25, 0.75, 0.75, 1.5])  # the recorded gaps, halved
    assert stats.sent == len(packets) and replay.log_stats.bad_crc == 1
    assert [m.roll for m in got] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in got} == {(1, 1)}  # recorded ids kept


def test_fast_replay_through_the_cli_gives_the_logs_depth_and_attitude():
    path = shared_file(LOG)
    start_s, window_s = 30.0, 20.0  # past the parameter download at the start: ~140 messages per log second
    # what the log says: the vehicle's last attitude and depth within the replayed window
    last: dict[str, mav2.MAVLink_message] = {}
    first_t = None
    for rec in read_tlog(path):
        first_t = rec.t_us if first_t is None else first_t
        if (rec.t_us - first_t) / 1e6 > start_s + window_s:
            break
        if rec.src == (1, 1) and rec.msg_type in ("ATTITUDE", "GLOBAL_POSITION_INT"):
            last[rec.msg_type] = mav2.MAVLink(None).decode(bytearray(rec.packet))
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(**FAST_LINK))
    tel = VehicleTelemetry(link, TelemetryConfig(), request_rates=False)
    tel.start()
    link.start()
    assert link.wait_open(5)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "replay-vehicle", str(path), "--connect", f"udpout:127.0.0.1:{port}",
             "--speed", "8", "--start", str(start_s), "--duration", str(window_s), "--json"],
            cwd=REPO, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        counters = json.loads(proc.stdout.strip().splitlines()[-1])
        att, gpi = last["ATTITUDE"], last["GLOBAL_POSITION_INT"]
        assert tel.wait_for(lambda s: s.roll == pytest.approx(att.roll) and s.depth_m is not None
                            and s.depth_m == pytest.approx(-gpi.relative_alt / 1000.0), 10), tel.latest
    finally:
        tel.stop()
        link.stop()
    latest = tel.latest
    assert latest.pitch == pytest.approx(att.pitch) and latest.yaw == pytest.approx(att.yaw)
    assert latest.depth_source == "global_position_int" and abs(latest.depth_m) < 0.5  # at the surface
    assert link.autopilot == (1, 1) and latest.mode is not None
    assert counters["sent"] > 1000 and counters["filtered_gcs"] > 0 and counters["log_seconds"] <= window_s


def test_replay_refuses_a_missing_or_foreign_file(tmp_path):
    notlog = tmp_path / "notes.tlog"
    notlog.write_text("hello, this is not MAVLink\n" * 10)
    result = run_merlion("replay-vehicle", str(notlog), "--connect", "udpout:127.0.0.1:9", timeout=60)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        f"merlion: error: {notlog}: not a MAVLink telemetry log (.tlog): no valid record found")


@pytest.mark.slow
def test_bench_link_reports_receive_share_and_pose_cost():
    path = shared_file(LOG)
    result = run_merlion("bench", "link", str(path), "--speeds", "4", "--start", "40", "--duration", "8", "--json",
                         timeout=180)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    (one,) = report["replay"]
    assert one["speed"] == 4.0 and one["sent"] > 500 and 0 < one["received"] <= one["sent"]
    assert report["pose_at_us"] > 0


_RSS_PROBE = """
import sys
from companion.config import MavlinkConfig
from vehicle.link.connection import MavLink
from vehicle.sim.replay import TlogReplay

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024

link = MavLink(sys.argv[2], MavlinkConfig(system_id=1, component_id=1), heartbeat=False)
link.start()
assert link.wait_open(5)
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # reset the peak (VmHWM) to the current RSS: imports' transient peaks must not hide growth
before = status("VmRSS")
replay = TlogReplay(sys.argv[1], link, speed=1e9)
stats = replay.run()
after = status("VmHWM")
link.stop()
print(before, after, stats.sent + stats.unsent, replay.log_stats.records)
"""


def test_a_large_log_replays_in_constant_memory(tmp_path):
    """A 16 MB log (in a child process, so that nothing else moves its peak RSS) replays with its peak memory
    growing by a small fraction of the file: the log is streamed, not read whole."""
    if not Path("/proc/self/clear_refs").exists():
        pytest.skip("needs Linux's /proc/self/clear_refs to measure peak memory")
    path = tmp_path / "large.tlog"
    packet = _packet(mav2.MAVLink_encapsulated_data_message(7, bytes(range(253))))
    records = 0
    with path.open("wb") as f:
        t0 = 1_700_000_000_000_000
        while f.tell() < 16 << 20:
            f.write(b"".join(_record(t0 + (records + i) * 1000, packet) for i in range(4096)))
            records += 4096
    size = path.stat().st_size
    proc = subprocess.run([sys.executable, "-c", _RSS_PROBE, str(path), f"udpout:127.0.0.1:{free_udp_port()}"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    before, after, handled, read = (int(x) for x in proc.stdout.split())
    assert read == handled == records
    assert after - before < size / 8, f"peak RSS grew {(after - before) / 2**20:.1f} MB for a {size / 2**20:.0f} MB log"
