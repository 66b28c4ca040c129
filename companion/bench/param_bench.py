"""PARAM_SET round trip as a ground station sees it: from sending PARAM_SET to receiving the PARAM_VALUE echo.

The live companion runs in this process on a generated dive (real time) with a simulated ArduSub on one UDP hub;
a ground-station socket on the hub sets MERL_K back and forth ``count`` times, each PARAM_SET sent once its
previous echo arrived. A MERL_K change goes through the summary's owner (it may trim the summary, which is stored
and announced before the echo), so the figure includes waiting for the batch the encoder is on.
"""

from __future__ import annotations

import socket
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import build_config
from companion.live.companion import LiveCompanion, LiveOptions
from companion.live.udp_hub import UdpHub
from vehicle.sim.vehicle import SimVehicle

GCS_SYSTEM = 255
GCS_COMPONENT = 190


@dataclass
class ParamRoundTrip:
    encoder: str
    count: int
    answered: int = 0
    p50_ms: float | None = None
    p95_ms: float | None = None
    max_ms: float | None = None
    frames_scored: int = 0
    samples_ms: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k != "samples_ms"}


class _GroundStation:
    """A bare UDP ground station on the hub: sends PARAM_SET, waits for the matching PARAM_VALUE."""

    def __init__(self, hub: UdpHub) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.hub = (hub.host, hub.port)
        self.mav = mav.MAVLink(None, srcSystem=GCS_SYSTEM, srcComponent=GCS_COMPONENT)
        self.mav.robust_parsing = True

    def send(self, msg: mav.MAVLink_message) -> None:
        self.sock.sendto(msg.pack(self.mav), self.hub)

    def hello(self) -> None:
        self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def set_and_wait(self, name: str, value: float, timeout: float) -> float | None:
        """Seconds from PARAM_SET to its PARAM_VALUE echo, None when none came within ``timeout``."""
        msg = mav.MAVLink_param_set_message(1, 100, name.encode(), float(value), mav.MAV_PARAM_TYPE_INT32)
        t0 = time.perf_counter()
        self.send(msg)
        deadline = t0 + timeout
        while time.perf_counter() < deadline:
            try:
                data = self.sock.recv(65535)
            except (TimeoutError, OSError):
                continue
            for m in self.mav.parse_buffer(data) or []:
                if m.get_type() == "PARAM_VALUE" and m.param_id == name and m.param_value == float(value):
                    return time.perf_counter() - t0
        return None

    def close(self) -> None:
        self.sock.close()


def run_param_bench(count: int = 40, *, encoder: str = "visual", fps: float = 5.0, warmup_s: float = 5.0,
                    pause_s: float = 0.2, timeout_s: float = 10.0) -> ParamRoundTrip:
    """``count`` MERL_K sets (alternating 6 and 5) against a running companion; their round trips."""
    gcs = None
    hub = UdpHub().start()
    sim = SimVehicle(hub.url)
    sim.start()
    with tempfile.TemporaryDirectory(prefix="merlion-params-") as store:
        cfg = build_config({
            "source": {"uri": "synthetic://dive?seconds=600", "fps": fps, "realtime": True},
            "encoder": {"name": encoder}, "queries": {"tau_ss": 0.0}, "sampler": {"k": 6},
            "mavlink": {"connection": hub.url}, "store": {"dir": str(Path(store))},
            "health": {"stall_after_s": 120.0},
        }, origin="param bench")
        companion = LiveCompanion(cfg, LiveOptions())
        result = ParamRoundTrip(encoder=encoder, count=count)
        try:
            companion.start()
            result.encoder = getattr(companion.encoder, "name", encoder)
            gcs = _GroundStation(hub)
            gcs.hello()
            time.sleep(warmup_s)  # the loops are running, the summary filling
            gcs.set_and_wait("MERL_K", 6, timeout_s)  # the hub now knows the ground station
            for i in range(count):
                took = gcs.set_and_wait("MERL_K", 5 if i % 2 == 0 else 6, timeout_s)
                if took is not None:
                    result.samples_ms.append(took * 1000.0)
                time.sleep(pause_s)
            result.frames_scored = companion.counters.frames_scored
        finally:
            companion.stop()
            sim.stop()
            hub.stop()
            if gcs is not None:
                gcs.close()
    result.answered = len(result.samples_ms)
    if result.samples_ms:
        ms = np.array(result.samples_ms)
        result.p50_ms = round(float(np.percentile(ms, 50)), 1)
        result.p95_ms = round(float(np.percentile(ms, 95)), 1)
        result.max_ms = round(float(ms.max()), 1)
    return result
