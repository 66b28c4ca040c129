"""How much telemetry the companion's link can take, what a pose lookup costs, and the link under many clients.

A real log is replayed by a separate ``merlion replay-vehicle`` process (so sender and receiver do not share an
interpreter) at increasing speeds into a ``MavLink`` with ``VehicleTelemetry`` attached, as in the live companion;
the share of packets that arrive tells where the receive thread saturates. ArduSub sends ~150-300 messages/s, so
the margin is the ratio to that.

``stress`` runs the on-board link with a simulated ArduSub process and N ground-station processes
(``vehicle/sim/gcs_load.py``) at once, and reports corrupted packets at each receiver and the receive loop's
longest stall.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vehicle.autopilot.pose import Pose
from vehicle.autopilot.pose_history import PoseHistory, euler_to_quaternion
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.camera.downlink import Downlink
from vehicle.camera.params import ParamSpec
from vehicle.errors import UserError as MerlionError
from vehicle.link.connection import MavLink
from vehicle.protocol.ftp import crc32_ardupilot
from vehicle.settings import MavlinkConfig, SurfaceConfig, TelemetryConfig
from vehicle.sim.gcs_load import REFUSED_QUERIES, WELL_FORMED_QUERIES, run_client


def _free_udp_port() -> int:

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def receive_rate(log: Path, speed: float, *, start_s: float, duration_s: float) -> dict[str, float]:
    """Replay ``duration_s`` of ``log`` at ``speed`` into a fresh link; packets sent, received, rates."""
    port = _free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(), heartbeat=False, name="bench")
    tel = VehicleTelemetry(link, TelemetryConfig(), request_rates=False)
    tel.start()
    link.start()
    if not link.wait_open(5):
        raise MerlionError("bench link: could not open a loopback UDP port")
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "-q", "replay-vehicle", str(log), "--connect",
             f"udpout:127.0.0.1:{port}", "--speed", str(speed), "--start", str(start_s), "--duration",
             str(duration_s), "--json"], capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            raise MerlionError(f"bench link: replay-vehicle failed: {proc.stderr.strip().splitlines()[-1:]}")
        sent = json.loads(proc.stdout.strip().splitlines()[-1])
        deadline = time.monotonic() + 3.0
        while link.rx_messages < sent["sent"] and time.monotonic() < deadline:  # let the receiver drain
            time.sleep(0.05)
    finally:
        tel.stop()
        link.stop()
    wall = max(sent["wall_seconds"], 1e-6)
    return {"speed": speed, "sent": sent["sent"], "received": link.rx_messages,
            "received_pct": round(100.0 * link.rx_messages / max(sent["sent"], 1), 2),
            "offered_msg_s": round(sent["sent"] / wall, 1), "received_msg_s": round(link.rx_messages / wall, 1)}


def pose_lookup_us(samples_hz: float = 10.0, history_s: float = 30.0, lookups: int = 5000) -> float:
    """Microseconds per ``PoseHistory.pose_at`` with a full history (depth, attitude, position at ``samples_hz``)."""

    h = PoseHistory(stale_after_s=1.0, history_s=history_s)
    n = int(samples_hz * history_s)
    for i in range(n):
        t = i / samples_hz
        h.add_depth(t, 5.0 + 0.01 * i, "global_position_int")
        h.add_attitude(t, euler_to_quaternion(0.01 * i, 0.0, 0.02 * i))
        h.add_local_position(t, 0.1 * i, 0.0, 5.0)
    rng = random.Random(0)
    times = [rng.uniform(0, history_s) for _ in range(lookups)]
    start = time.perf_counter()
    for t in times:
        h.pose_at(t)
    return (time.perf_counter() - start) / lookups * 1e6


def run_link_bench(log: Path, speeds: list[float], *, start_s: float = 30.0, duration_s: float = 30.0,
                   report: Callable[[str], None] | None = None) -> dict[str, object]:
    results = []
    for speed in speeds:
        r = receive_rate(log, speed, start_s=start_s, duration_s=duration_s)
        results.append(r)
        if report is not None:
            report(f"bench link: {speed:g}x: offered {r['offered_msg_s']:.0f} msg/s, received "
                   f"{r['received_pct']:.1f}% ({r['received']}/{r['sent']})")
    pose_us = pose_lookup_us()
    if report is not None:
        report(f"bench link: pose_at {pose_us:.1f} us per lookup (30 s of 10 Hz history)")
    return {"log": str(log), "replay": results, "pose_at_us": round(pose_us, 2)}


# ---- many clients at once: corrupted packets and receive-loop stalls ------------------------------------------

STRESS_BUDGET = 250_000
"""Bytes/s for the stress run: a BlueROV2 tether is Ethernet, and a 1280x720 frame is ~300 KB on FTP."""
STRESS_PARAM = ("MERL_STRESS", 1.0, 9.0)
"""The parameter the stress clients set; its change handler is slow on purpose (a lock wait and an fsync)."""


class _Refused(Exception):
    """Not a ValueError: how the app refuses a queries file (its error type), which once escaped as silence."""


def _stress_frames(count: int, width: int, height: int) -> list[Any]:
    """Summary frames with textured full-size images (their JPEG encoding costs what a real frame's does)."""


    frames = []
    for i in range(count):
        rng = np.random.default_rng(i)
        img = cv2.resize((rng.random((height // 8, width // 8, 3)) * 255).astype(np.uint8), (width, height),
                         interpolation=cv2.INTER_CUBIC)
        pose = Pose(time=1_700_000_000.0 + i, age_s=0.05, stale=False, depth_m=3.0 + i, depth_source="sim")
        frames.append(SummaryFrame(image_index=i, frame_index=10 * i, time_s=float(i),
                                   capture_time=1_700_000_000.0 + i, score=0.5, image=img, pose=pose))
    held = [f.image_index for f in frames]
    return [SummaryEvent("added", f, held[: k + 1]) for k, f in enumerate(frames)]


@dataclass
class SummaryFrame:
    """A summary frame as the Downlink reads it (vehicle/camera/capture_frame.py), for the benches that drive it."""

    image_index: int
    frame_index: int
    time_s: float
    capture_time: float
    score: float
    image: Any
    pose: Any
    enhanced: bool = False
    raw_image: Any = None
    topic: str = ""  # what the Downlink reads for a frame without one
    raw_score: float | None = None


@dataclass
class SummaryEvent:
    kind: str
    frame: SummaryFrame
    summary: list[int]


def _slow_param_change(name: str, value: float) -> None:
    """What the live app's handler costs: a wait on the pipeline lock and a crash-safe save (fsync)."""
    time.sleep(0.05)
    with tempfile.NamedTemporaryFile() as f:
        f.write(f"{name}={value}\n".encode())
        f.flush()
        os.fsync(f.fileno())


def _refuse_queries(topics: list) -> None:
    raise _Refused(f"queries refused by the app ({len(topics)} topic(s))")


def stress(clients: int, duration_s: float, *, frames: int = 6, width: int = 1280, height: int = 720,
           report: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The on-board link (``MavLink`` + ``Downlink``) with a simulated ArduSub process and ``clients`` ground
    station processes at once for ``duration_s``: corrupted packets at each receiver, the receive loop's longest
    stall, downloads that differ from the on-board tree, refused uploads answered, autopilot-lost events."""


    port = _free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100), name="stress")
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=STRESS_BUDGET, push=True, ftp_writable=True),
                       params=[ParamSpec(STRESS_PARAM[0], 5.0, STRESS_PARAM[1], STRESS_PARAM[2], integer=True)])
    surface.on_param_changed(_slow_param_change, replay=False)
    surface.on_queries_changed(_refuse_queries)
    lost: list[float] = []
    link.on_autopilot(lambda alive: None if alive else lost.append(time.monotonic()))
    link.start()
    if not link.wait_open(5):
        raise MerlionError("bench link: could not open a loopback UDP port")
    surface.start()
    for event in _stress_frames(frames, width, height):
        surface.publish(event)
    sim = subprocess.Popen([sys.executable, "-m", "companion", "-q", "sim-vehicle", "--connect",
                            f"udpout:127.0.0.1:{port}", "--duration", str(duration_s + 30)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = multiprocessing.get_context("spawn")
    results = ctx.Queue()
    procs = [ctx.Process(target=run_client, args=(f"udpout:127.0.0.1:{port}", 200 + i, duration_s, STRESS_PARAM,
                                                  i, results, (REFUSED_QUERIES, WELL_FORMED_QUERIES)), daemon=True)
             for i in range(clients)]
    try:
        if not link.wait_autopilot(20):
            raise MerlionError("bench link: the simulated vehicle never sent a heartbeat")
        for p in procs:
            p.start()
        got = [results.get(timeout=duration_s + 120) for _ in procs]
        for p in procs:
            p.join(10)
        tree = {path: surface.tree.read(path) for r in got for path in r.get("downloads", {})}
    finally:
        for p in procs:
            if p.is_alive():
                p.kill()
        sim.terminate()
        sim.wait(10)
        surface.stop()
        link.stop()

    mismatched = 0
    for r in got:
        for path, copies in r.get("downloads", {}).items():
            data = tree.get(path)
            want = None if data is None else [len(data), crc32_ardupilot(data)]
            mismatched += sum(1 for c in copies if want is not None and c != want)
    out = {
        "clients": clients, "duration_s": duration_s,
        "corrupted": sum(int(r.get("corrupted", 0)) for r in got),
        "corrupted_by_client": [r.get("corrupted") for r in got],
        "received_by_client": [r.get("received") for r in got],
        "rx_longest_ms": round(link.rx_longest_s * 1000.0, 2),
        "rx_longest_cpu_ms": round(link.rx_longest_cpu_s * 1000.0, 2),
        "rx_messages": link.rx_messages, "rx_over_50ms": link.rx_slow,
        "worker_longest_ms": round(max(surface.ftp_worker.longest_s, surface.control_worker.longest_s) * 1000, 1),
        "downloads": sum(len(c) for r in got for c in r.get("downloads", {}).values()),
        "download_failures": sum(int(r.get("download_failures", 0)) for r in got),
        "failure_reasons": [f for r in got for f in r.get("failure_reasons", [])],
        "mismatched": mismatched,
        "lists": sum(int(r.get("lists", 0)) for r in got),
        "params_set": sum(int(r.get("params_set", 0)) for r in got),
        "param_echoes": sum(int(r.get("param_echoes", 0)) for r in got),
        "refused_uploads": [a for r in got for a in r.get("refused_upload", [])],
        "autopilot_lost": len(lost), "errors": [r["error"] for r in got if "error" in r],
    }
    if report is not None:
        report(f"bench link: {clients} client(s), {duration_s:g} s: {out['corrupted']} corrupted packets, "
               f"receive loop longest stall {out['rx_longest_ms']:.1f} ms wall / {out['rx_longest_cpu_ms']:.1f} ms "
               f"CPU, {out['rx_over_50ms']} of {out['rx_messages']} messages over 50 ms (slowest request on a worker "
               f"{out['worker_longest_ms']:.0f} ms), {out['downloads']} downloads ({out['mismatched']} differ), "
               f"autopilot lost {out['autopilot_lost']} times")
    return out
