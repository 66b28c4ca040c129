"""What a signed ground station still receives while an unsigned flood asks the companion for everything.

Real parts on loopback: the companion's ``MavLink`` signing with a key and its ``Downlink`` at the configured budget,
a signed pymavlink ground station that only listens, and ``vehicle/sim/unsigned_flood.py`` in a process of its own.
A new summary frame is published every ``capture_every_s`` (as the live companion sends it: a capture, its line,
a thumbnail push, the trimmed frame's line and the 1 Hz status values) through three
phases of ``seconds`` each: no flood, the flood, and after it. Reported per phase: the share of the captures
published in it that reached the station (within ``GRACE_S``), the pushed thumbnail chunks per second, and the
answers to the flood the station saw go by (the companion's UDP server sends every packet to every peer); after the
flood, answers later than the requesters' quiet time (``QUIET_S``) mean answers to a peer that has gone.
"""

from __future__ import annotations

import multiprocessing
import select
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vehicle.autopilot.pose import Pose
from vehicle.camera.downlink import Downlink
from vehicle.camera.params import ParamSpec
from vehicle.errors import UserError
from vehicle.link.connection import MavLink
from vehicle.link.fair_replies import QUIET_S
from vehicle.link.signing import key_from_bytes
from vehicle.settings import MavlinkConfig, SurfaceConfig
from vehicle.sim.link_bench import SummaryEvent, SummaryFrame
from vehicle.sim.unsigned_flood import FIRST_ID, send_flood

PASSPHRASE = b"flood bench key"
GRACE_S = 5.0
"""A capture counts as received when it arrives within this long of being published."""
_MAGIC = (bytes([mavlink2.PROTOCOL_MARKER_V2]), bytes([mavlink2.PROTOCOL_MARKER_V1]))
ANSWERS = frozenset({"PARAM_VALUE", "FILE_TRANSFER_PROTOCOL", "COMMAND_ACK"})
PARAMS = [ParamSpec(f"MERL_P{i}", float(i), 0, 100) for i in range(8)]
KEEP = 4
"""Summary size K: from the fifth frame on, each new one trims the oldest out, as the live summary does."""


@dataclass
class SignedStation:
    """The signed ground station's ears: when each capture, thumbnail chunk and answer to the flood arrived.

    It reads the station's socket datagram by datagram, as the companion's link does: pymavlink's own reader
    (``recv_match``) parses UDP as one byte stream, so a garbage datagram that begins like a packet takes the next
    datagram as its tail and both are lost (415 of 500 valid packets after the flood's garbage, measured). Behind a
    router that forwards the flood's garbage to the station, that lost ~10% of the captures the companion sent."""

    gcs: mavutil.mavfile
    captures: dict[int, float] = field(default_factory=dict)
    chunks: list[float] = field(default_factory=list)
    answers: list[float] = field(default_factory=list)
    wire: list[tuple[float, int]] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)
    truncated: int = 0
    """Datagrams that left half a packet (garbage) before the next began."""
    last_unsigned: float = 0.0
    """When the last unsigned or garbage datagram arrived (the flood's end, seen from the station)."""

    def _parser(self, before: mavlink2.MAVLink | None = None) -> mavlink2.MAVLink:
        """A parser with an empty buffer; it keeps ``before``'s signing state (the streams' last timestamps)."""
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        if before is not None:
            parser.signing = before.signing
        else:
            parser.signing.secret_key = self.gcs.mav.signing.secret_key  # unsigned messages come out as BAD_DATA
        return parser

    def run(self) -> None:
        sock = self.gcs.port
        parser = self._parser()
        while not self.stop.is_set():
            if not select.select([sock], [], [], 0.1)[0]:
                continue
            try:
                data = sock.recv(65535)
            except OSError:  # a refusal reported, or the socket closed at the end
                continue
            if parser.buf_len() and data[:1] in _MAGIC:
                self.truncated += 1
                parser = self._parser(parser)
            try:
                msgs = parser.parse_buffer(data) or []
            except mavlink2.MAVError:
                parser = self._parser(parser)
                continue
            now = time.monotonic()
            for msg in msgs:
                self._note(msg, now)

    def _note(self, msg: mavlink2.MAVLink_message, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":  # unsigned or garbage: the flood, where a router forwards it to the station too
            self.last_unsigned = now
            return
        self.wire.append((now, len(msg.get_msgbuf())))
        if kind == "CAMERA_IMAGE_CAPTURED":
            self.captures.setdefault(msg.image_index, now)
        elif kind == "ENCAPSULATED_DATA":
            self.chunks.append(now)
        elif kind in ANSWERS and FIRST_ID <= getattr(msg, "target_system", FIRST_ID) < 250:
            self.answers.append(now)  # PARAM_VALUE has no target: the station asked for none


def _frame(index: int) -> SummaryFrame:
    rng = np.random.default_rng(index)
    image = cv2.resize((rng.random((34, 60, 3)) * 255).astype(np.uint8), (480, 270), interpolation=cv2.INTER_CUBIC)
    now = time.time()
    return SummaryFrame(image_index=index, frame_index=index, time_s=float(index), capture_time=now, score=0.8,
                        image=image, pose=Pose(time=now, age_s=0.0, stale=False, depth_m=5.0), topic="main")


def _summary_step(surface: Downlink, held: list[SummaryFrame], index: int) -> None:
    """What the live companion sends for a new summary frame with K = ``KEEP``: the oldest frame trimmed out (a
    STATUSTEXT), the new one added (a capture, a STATUSTEXT, a push), and its status values (six a second)."""
    if len(held) == KEEP:
        gone = held.pop(0)
        surface.publish(SummaryEvent("removed", gone, [f.image_index for f in held]))
    held.append(_frame(index))
    surface.publish(SummaryEvent("added", held[-1], [f.image_index for f in held]))
    surface.update_status(fps=9.5, seen_fps=15.0, score=0.8, summary=len(held), depth_m=5.0)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure_flood(seconds: float, *, rate: float = 1500.0, ids: int = 200, budget: int = 2000,
                  capture_every_s: float = 2.0, report: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The three phases (see the module docstring); a dict of figures per phase."""
    with tempfile.TemporaryDirectory(prefix="merlion-flood-") as tmp:
        key_file = Path(tmp) / "signing.key"
        key_file.write_bytes(PASSPHRASE + b"\n")
        port = _free_port()
        link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100,
                                                                signing_key_file=str(key_file)), name="flood")
        link.start()
        if not link.wait_open(5):
            raise UserError("bench link: could not open a loopback UDP port")
        surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=budget), params=PARAMS)
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190,
                                         dialect="ardupilotmega")
        gcs.setup_signing(key_from_bytes(PASSPHRASE), sign_outgoing=True)
        station = SignedStation(gcs)
        listener = threading.Thread(target=station.run, name="flood-station", daemon=True)
        try:
            gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            listener.start()
            surface.start()
            return _phases(surface, station, port, seconds, rate, ids, capture_every_s, report)
        finally:
            station.stop.set()
            listener.join(5)
            surface.stop()
            link.stop()
            gcs.close()


def _phases(surface: Downlink, station: SignedStation, port: int, seconds: float, rate: float, ids: int,
            every: float, report: Callable[[str], None] | None) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    results = ctx.Queue()
    flood = ctx.Process(target=send_flood, args=(port, rate, seconds), kwargs={"ids": ids, "results": results},
                        daemon=True)
    published: list[tuple[int, float]] = []
    held: list[SummaryFrame] = []
    phases: dict[str, tuple[float, float]] = {}
    index = 0
    time.sleep(1.0)  # the start-up line goes first
    try:
        for name in ("before", "flood", "after"):
            start = time.monotonic()
            if name == "flood":
                flood.start()
            due = start
            while time.monotonic() - start < seconds:
                index += 1
                published.append((index, time.monotonic()))
                _summary_step(surface, held, index)
                due += every
                time.sleep(max(0.0, min(due, start + seconds) - time.monotonic()))
            phases[name] = (start, time.monotonic())
        time.sleep(GRACE_S)
        flood.join(30)
        if flood.exitcode != 0:
            raise UserError(f"bench link: the flood process failed (exit {flood.exitcode})")
        sent = results.get(timeout=10)
    finally:
        if flood.is_alive():
            flood.kill()
    out: dict[str, Any] = {"seconds": seconds, "rate": rate, "ids": ids, "budget": surface.budget.rate,
                           "flood_sent": sent, "replies": surface.replies.stats(),
                           "unsigned_answer_bytes": surface.unsigned_slice.sent,
                           "elapsed_s": round(time.monotonic() - phases["before"][0], 1),
                           "requests_dropped": sum(surface.requests.stats().values())}
    for name, (start, end) in phases.items():
        mine = [(i, t) for i, t in published if start <= t < end]
        got = sum(1 for i, t in mine if station.captures.get(i, float("inf")) - t <= GRACE_S)
        out[name] = {"captures": len(mine), "captures_received": got,
                     "captures_per_s": round(got / (end - start), 3),
                     "chunks_per_s": round(sum(start <= t < end for t in station.chunks) / (end - start), 2),
                     "answers_to_flood": sum(start <= t < end for t in station.answers),
                     "wire_bytes_per_s": round(sum(n for t, n in station.wire if start <= t < end) / (end - start))}
    flood_end = phases["flood"][1]
    out["answers_after_quiet"] = sum(t > flood_end + QUIET_S + 1.0 for t in station.answers)
    base = out["before"]
    for name in ("flood", "after"):
        phase = out[name]
        phase["captures_pct_of_before"] = round(100.0 * phase["captures_per_s"] / max(base["captures_per_s"], 1e-9), 1)
        phase["chunks_pct_of_before"] = round(100.0 * phase["chunks_per_s"] / max(base["chunks_per_s"], 1e-9), 1)
    if report is not None:
        f = out["flood"]
        report(f"bench link: unsigned flood of {sent / seconds:.0f} datagrams/s from {ids} ids for {seconds:g} s "
               f"at {out['budget']:.0f} B/s: captures received {f['captures_received']}/{f['captures']} "
               f"({f['captures_pct_of_before']:.0f}% of the rate without it), thumbnail chunks "
               f"{f['chunks_per_s']:.1f}/s ({f['chunks_pct_of_before']:.0f}%), answers to the flood seen "
               f"{f['answers_to_flood']}; after it: {out['answers_after_quiet']} answers later than "
               f"{QUIET_S:g} s + 1 s")
    return out
