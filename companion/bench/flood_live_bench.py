"""The issue 46 flood against the whole live companion: what a signed ground station still receives.

``vehicle/sim/flood_bench.py`` floods the ``Downlink`` alone; this runs the setup the issue measured, every part a
process of its own on loopback with one signing key: ``merlion run`` on a looping video file (the cheap visual
encoder), ``merlion sim-vehicle`` (the simulated ArduSub, signing), a UDP hub as the vehicle's router (BlueOS'
router forwards every datagram to every endpoint, so the flood reaches the companion, the autopilot and the ground
station alike), a signed pymavlink ground station on the hub that sends its heartbeat and listens, and the flood of
``vehicle/sim/unsigned_flood.py`` sent to the hub. Three phases: ``seconds`` without the flood, ``seconds`` of it,
and ``after_s`` after it. Reported per phase: captures the companion made (its store's change log), captures the
station received (CAMERA_IMAGE_CAPTURED within ``GRACE_S`` of being made), thumbnail chunks received, the
companion's CPU; after the flood, answers to the flood later than the requesters' quiet time; and how many log lines
the companion wrote about refused unsigned messages.
"""

from __future__ import annotations

import json
import multiprocessing
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import psutil
import yaml
from pymavlink import mavutil

from companion.errors import MerlionError
from companion.live.udp_hub import RECEIVE_BUFFER, UdpHub
from vehicle.link.endpoint import ask_receive_buffer
from vehicle.link.fair_replies import QUIET_S
from vehicle.link.signing import key_from_bytes
from vehicle.sim.flood_bench import SignedStation
from vehicle.sim.unsigned_flood import send_flood

PACKAGE_ROOT = Path(__file__).resolve().parents[2]
PASSPHRASE = "live flood bench key"
GRACE_S = 5.0
"""A capture counts as received when it arrives within this long of being made."""
START_TIMEOUT_S = 120.0
CAPTURE_EVERY_S = 2.0
SUMMARY_K = 1000
"""Larger than the captures of the longest bench (its summary never trims: each capture is one new frame)."""
REFUSAL_TEXT = " ignored"
"""What the signing code's warnings about refused unsigned messages say (``vehicle/link/refusal_log.py``)."""


def _serve_hub(outputs: list[tuple[str, int]], ready: Any, stop: Any) -> None:
    """The router, in a process of its own (BlueOS' is a program of its own too): its port goes on ``ready``."""
    hub = UdpHub(outputs=outputs).start()
    ready.put(hub.port)
    stop.wait()
    ready.put({"forwarded": hub.forwarded, "forgotten": hub.forgotten})
    hub.stop()


def _write_clip(path: Path, seconds: float = 300.0, fps: float = 5.0) -> Path:
    """An MJPEG clip of the generated dive, 3-s segments each with fresh detail: no frame of it is a duplicate of
    another, so every frame the gate lets through enters a summary that is still warming up (see ``_config``)."""
    from companion.sources.synthetic import SyntheticSource

    source = SyntheticSource("synthetic://dive?seconds=3&width=320&height=180", fps=fps, realtime=False)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (320, 180))
    for i, frame in enumerate(source):
        if i >= seconds * fps:
            break
        writer.write(frame.image)
    writer.release()
    return path


def _config(clip: Path, hub_url: str, store: Path) -> dict[str, Any]:
    """A capture every ``CAPTURE_EVERY_S`` of footage, as steady as the flood bench's: the gate encodes a frame only
    when that long has passed (never for a difference), every frame passes tau_ss, and a summary of ``SUMMARY_K``
    takes every distinct frame; the rest is the default (2,000 B/s downlink, status at 1 Hz, thumbnails pushed)."""
    return {"source": {"uri": str(clip), "fps": 5, "realtime": True, "loop": True},
            "encoder": {"name": "visual"}, "queries": {"tau_ss": 0.0}, "sampler": {"k": SUMMARY_K},
            "gate": {"mode": "difference", "threshold": 255, "max_gap_s": CAPTURE_EVERY_S, "max_gap_share": 0.0},
            "mavlink": {"connection": hub_url}, "store": {"dir": str(store)}, "health": {"stall_after_s": 60}}


def _merlion(*args: str, log: Path) -> subprocess.Popen:
    out = log.open("w")
    try:
        return subprocess.Popen([sys.executable, "-m", "companion", *args], stdout=out, stderr=subprocess.STDOUT,
                                cwd=PACKAGE_ROOT)  # the same companion as this bench's, installed or not
    finally:
        out.close()


def _added(store: Path) -> list[tuple[int, float]]:
    """(image index, wall time) of every frame the companion's store added so far."""
    out = []
    try:
        lines = (store / "changes.jsonl").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            entry = json.loads(line)
        except ValueError:
            continue  # a line being written
        if entry.get("kind") == "added":
            out.append((int(entry["image_index"]), float(entry["t"])))
    return out


def _wait(predicate: Callable[[], bool], timeout: float, what: str, procs: list[subprocess.Popen]) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        for p in procs:
            if p.poll() is not None:
                raise MerlionError(f"bench link --live: {p.args[3]} exited ({p.returncode}) before {what}")
        if time.monotonic() > deadline:
            raise MerlionError(f"bench link --live: no {what} within {timeout:g} s")
        time.sleep(0.2)


def measure_live_flood(seconds: float, *, after_s: float | None = None, rate: float = 1500.0, ids: int = 200,
                       report: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The three phases (see the module docstring); a dict of figures per phase."""
    after_s = seconds / 2 if after_s is None else after_s
    ctx = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="merlion-live-flood-") as tmp_name:
        tmp = Path(tmp_name)
        key = tmp / "signing.key"
        key.write_text(PASSPHRASE + "\n")
        store = tmp / "store"
        ready, stop = ctx.Queue(), ctx.Event()
        hub = ctx.Process(target=_serve_hub, args=([], ready, stop), daemon=True)
        hub.start()
        hub_port = ready.get(timeout=30)
        hub_url = f"udpout:127.0.0.1:{hub_port}"
        # the station joins the router as every udpout client does: learnt from its first (signed) heartbeat
        gcs = mavutil.mavlink_connection(hub_url, source_system=255, source_component=190, dialect="ardupilotmega")
        gcs.setup_signing(key_from_bytes(PASSPHRASE.encode()), sign_outgoing=True)
        ask_receive_buffer(gcs.port, RECEIVE_BUFFER)  # as the router's: this Python reader is slower than QGC's
        clip = _write_clip(tmp / "dive.avi")
        cfg = tmp / "companion.yaml"
        cfg.write_text(yaml.safe_dump(_config(clip, hub_url, store)))
        sim = _merlion("sim-vehicle", "--connect", hub_url, "--signing-key", str(key), log=tmp / "sim.log")
        companion = _merlion("run", "--config", str(cfg), "--signing-key", str(key), log=tmp / "companion.log")
        station = SignedStation(gcs)
        beats = threading.Event()
        threads = [threading.Thread(target=station.run, name="live-flood-station", daemon=True),
                   threading.Thread(target=_heartbeats, args=(gcs, beats), name="live-flood-gcs", daemon=True)]
        for t in threads:
            t.start()
        try:
            _wait(lambda: bool(station.captures), START_TIMEOUT_S, "capture at the ground station",
                  [sim, companion])
            out = _phases(station, store, companion, hub_port, seconds, after_s, rate, ids, ctx)
            out["companion_log_refusal_lines"] = sum(
                "WARNING" in line and REFUSAL_TEXT in line
                for line in (tmp / "companion.log").read_text(errors="replace").splitlines())
            ports = {"router": [hub_port], "ground station": [gcs.port.getsockname()[1]],
                     "companion": _udp_ports(companion.pid), "autopilot": _udp_ports(sim.pid)}
            out["udp_receive_drops"] = _udp_drops(ports)
            stop.set()
            out["hub"] = ready.get(timeout=10)
        finally:
            station.stop.set()
            beats.set()
            for proc in (companion, sim):
                proc.terminate()
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    proc.kill()
            stop.set()
            hub.join(10)
            if hub.is_alive():
                hub.kill()
            for t in threads:
                t.join(5)
            gcs.close()
    if report is not None:
        report(_line(out))
    return out


def _udp_ports(pid: int) -> list[int]:
    try:
        return [c.laddr.port for c in psutil.Process(pid).net_connections(kind="udp") if c.laddr]
    except (psutil.Error, OSError):
        return []


def _udp_drops(ports: dict[str, list[int]]) -> dict[str, int] | None:
    """Datagrams each part's sockets lost because their receive buffer was full (the kernel's per-socket ``drops``
    in /proc/net/udp): where a capture that never arrived was lost. None off Linux."""
    try:
        rows = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    by_port: dict[int, int] = {}
    for row in rows:
        cols = row.split()
        if len(cols) >= 13:
            port = int(cols[1].rsplit(":", 1)[1], 16)
            by_port[port] = by_port.get(port, 0) + int(cols[-1])
    return {name: sum(by_port.get(p, 0) for p in numbers) for name, numbers in ports.items()}


def _heartbeats(gcs: mavutil.mavfile, stop: threading.Event) -> None:
    """A ground station's 1 Hz heartbeat (signed): the router keeps it as a peer, the autopilot sees its GCS."""
    while not stop.is_set():
        gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        stop.wait(1.0)


def _phases(station: SignedStation, store: Path, companion: subprocess.Popen, hub_port: int, seconds: float,
            after_s: float, rate: float, ids: int, ctx: Any) -> dict[str, Any]:
    results = ctx.Queue()
    flood = ctx.Process(target=send_flood, args=(hub_port, rate, seconds), kwargs={"ids": ids, "results": results},
                        daemon=True)
    cpu = psutil.Process(companion.pid)
    phases: dict[str, tuple[float, ...]] = {}  # name -> wall start, end, monotonic start, end, CPU seconds
    try:
        for name, length in (("before", seconds), ("flood", seconds), ("after", after_s)):
            times = cpu.cpu_times()
            busy = times.user + times.system
            wall, mono = time.time(), time.monotonic()
            if name == "flood":
                flood.start()
            time.sleep(length)
            times = cpu.cpu_times()
            phases[name] = (wall, time.time(), mono, time.monotonic(), times.user + times.system - busy)
        time.sleep(GRACE_S)
        flood.join(30)
        sent = results.get(timeout=10)
    finally:
        if flood.is_alive():
            flood.kill()
    made = _added(store)
    # the station stamps with the monotonic clock, the store with the wall clock: one offset joins them
    offset = time.time() - time.monotonic()
    out: dict[str, Any] = {"seconds": seconds, "after_s": after_s, "rate": rate, "ids": ids, "flood_sent": sent}
    for name, (wall0, wall1, mono0, mono1, busy) in phases.items():
        mine = [(i, t) for i, t in made if wall0 <= t < wall1]
        got = sum(1 for i, t in mine if station.captures.get(i, float("inf")) + offset - t <= GRACE_S)
        late = sum(1 for i, t in mine if GRACE_S < station.captures.get(i, float("inf")) + offset - t < float("inf"))
        length = wall1 - wall0
        out[name] = {"captures_made": len(mine), "captures_received": got, "captures_late": late,
                     "received_per_min": round(60.0 * got / length, 1),
                     "chunks": sum(mono0 <= t < mono1 for t in station.chunks),
                     "chunks_per_s": round(sum(mono0 <= t < mono1 for t in station.chunks) / length, 2),
                     "answers_to_flood": sum(mono0 <= t < mono1 for t in station.answers),
                     "companion_cpu_pct": round(100.0 * busy / length, 1)}
    # the flood's process starts (and so ends) a moment after its phase: its last datagram at the station counts
    flood_end = max(phases["flood"][3], station.last_unsigned)
    out["flood_ended_after_phase_s"] = round(flood_end - phases["flood"][3], 2)
    out["answers_after_quiet"] = sum(t > flood_end + QUIET_S + 1.0 for t in station.answers)
    out["last_answer_after_flood_s"] = round(max((t - flood_end for t in station.answers), default=0.0), 2)
    base = max(out["before"]["received_per_min"], 1e-9)
    for name in ("flood", "after"):
        out[name]["received_pct_of_before"] = round(100.0 * out[name]["received_per_min"] / base, 1)
    return out


def _line(out: dict[str, Any]) -> str:
    b, f, a = out["before"], out["flood"], out["after"]
    return (f"bench link --live: flood of {out['flood_sent'] / out['seconds']:.0f} datagrams/s from {out['ids']} ids "
            f"through the router: captures received per minute {b['received_per_min']:g} before "
            f"({b['captures_received']}/{b['captures_made']}), {f['received_per_min']:g} during "
            f"({f['captures_received']}/{f['captures_made']}, {f['received_pct_of_before']:.0f}%), "
            f"{a['received_per_min']:g} after ({a['received_pct_of_before']:.0f}%); thumbnail chunks/s "
            f"{b['chunks_per_s']:g} / {f['chunks_per_s']:g} / {a['chunks_per_s']:g}; companion CPU "
            f"{b['companion_cpu_pct']:g}% / {f['companion_cpu_pct']:g}% / {a['companion_cpu_pct']:g}%; answers to "
            f"the flood later than {QUIET_S:g} s + 1 s after it: {out['answers_after_quiet']} (the last "
            f"{out['last_answer_after_flood_s']:g} s after it); log lines about "
            f"refused unsigned messages: {out['companion_log_refusal_lines']}; datagrams dropped at full receive "
            f"buffers: {out['udp_receive_drops']}")
