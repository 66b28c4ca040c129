"""Real endpoints for the surface-link tests: our companion link, a pymavlink ground station, a lossy relay.

Everything here is a real UDP socket on 127.0.0.1 with an OS-assigned port; the ground station is pymavlink's
own ``mavutil`` connection (what MAVProxy uses), so the tests speak to the companion as a real client would.
"""

from __future__ import annotations

import random
import select
import socket
import threading
import time

import cv2
import numpy as np
from pymavlink import mavutil

from companion.config import MavlinkConfig
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.conftest import free_udp_port
from vehicle.autopilot.pose import Pose
from vehicle.link.connection import MavLink

GCS_SYSTEM, GCS_COMPONENT = 255, 190


def scene(seed: int, width: int = 480, height: int = 270) -> np.ndarray:
    """A textured BGR frame that JPEG cannot shrink to nothing (blurred noise plus shapes), different per seed."""
    rng = np.random.default_rng(seed)
    img = (rng.random((height // 8, width // 8, 3)) * 255).astype(np.uint8)
    img = cv2.resize(img, (width, height), interpolation=cv2.INTER_CUBIC)
    for _ in range(6):
        center = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        color = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(img, center, int(rng.integers(10, 60)), color, -1)
    return img


def summary_frame(index: int, *, depth: float | None = 12.5, lat: float | None = None) -> SummaryFrame:
    # image 5's pose has an infinite age, as one with no telemetry sample yet: index.json must stay strict JSON
    pose = Pose(time=1_700_000_000.0 + index, age_s=float("inf") if index == 5 else 0.05, stale=False, depth_m=depth,
                depth_source="global_position_int", roll=0.01, pitch=-0.02, yaw=1.2,
                q=(0.8253, 0.0, 0.0, 0.5646), heading_deg=68.8, lat=lat, lon=None if lat is None else 103.8)
    return SummaryFrame(image_index=index, frame_index=10 * index, time_s=2.0 * index,
                        capture_time=1_700_000_000.0 + index, score=0.8, image=scene(index),
                        feature=np.ones(8, np.float32), pose=pose)


def added(index: int, held: list[int]) -> SummaryEvent:
    return SummaryEvent("added", summary_frame(index), summary=list(held))


def removed(index: int, held: list[int]) -> SummaryEvent:
    return SummaryEvent("removed", summary_frame(index), summary=list(held))


def companion_link(port: int, **cfg) -> MavLink:
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100, **cfg))
    link.start()
    assert link.wait_open(5)
    return link


def ground_station(port: int) -> mavutil.mavfile:
    """A pymavlink connection to the companion that has said hello (so the udpin side knows where to answer)."""
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=GCS_SYSTEM,
                                     source_component=GCS_COMPONENT, dialect="ardupilotmega")
    gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    return gcs


def wait_for(gcs: mavutil.mavfile, kind: str | list[str], timeout: float = 5.0, cond=None):
    """The next message of ``kind`` (and satisfying ``cond``) within ``timeout`` seconds, else None."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = gcs.recv_match(type=kind, blocking=True, timeout=max(0.01, end - time.monotonic()))
        if msg is not None and (cond is None or cond(msg)):
            return msg
    return None


class LossyRelay:
    """A UDP relay between a client and the companion that drops ``loss`` of the datagrams each way."""

    def __init__(self, target_port: int, loss: float, seed: int = 7) -> None:
        self.port = free_udp_port()
        self._front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._front.bind(("127.0.0.1", self.port))
        self._back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._back.connect(("127.0.0.1", target_port))
        self._client: tuple[str, int] | None = None
        self._rng = random.Random(seed)
        self.loss = loss
        self.dropped = 0
        self.passed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._front, self._back], [], [], 0.05)
            for sock in ready:
                data, addr = sock.recvfrom(65536)
                if sock is self._front:
                    self._client = addr
                if self._rng.random() < self.loss:
                    self.dropped += 1
                    continue
                self.passed += 1
                if sock is self._front:
                    self._back.send(data)
                elif self._client is not None:
                    self._front.sendto(data, self._client)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._front.close()
        self._back.close()
