"""How much telemetry the companion's link can take, and what a pose lookup costs.

A real log is replayed by a separate ``merlion replay-vehicle`` process (so sender and receiver do not share an
interpreter) at increasing speeds into a ``MavLink`` with ``VehicleTelemetry`` attached, as in the live companion;
the share of packets that arrive tells where the receive thread saturates. ArduSub sends ~150-300 messages/s, so
the margin is the ratio to that.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.errors import UserError as MerlionError
from vehicle.link.connection import MavLink
from vehicle.settings import MavlinkConfig, TelemetryConfig


def _free_udp_port() -> int:
    import socket

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
    from vehicle.autopilot.pose_history import PoseHistory, euler_to_quaternion

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
