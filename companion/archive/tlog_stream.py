"""Read a dive log (.tlog) record by record and tag moments with the vehicle's pose, as the live companion does.

pymavlink's log reader streams the file (it never holds it whole) and stamps every message with its record time
(``_timestamp``, the recorder's wall clock). ``LogLink`` hands those messages to ``VehicleTelemetry`` through the
same small interface a live ``MavLink`` offers (subscribe, on_autopilot, autopilot), with the record time as the
arrival clock, so the depth source priority, the boot-clock mapping and the pose interpolation are the live code,
not a copy. A pose is read once the log has gone past the asked time by more than the stale limit, so the
telemetry keeps only its usual short history however long the log is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.errors import MerlionError, UsageError
from vehicle.autopilot.pose import Pose
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.autopilot_watch import is_autopilot_heartbeat
from vehicle.settings import TelemetryConfig

Message = mav2.MAVLink_message


def stream_tlog(path: str | Path) -> Iterator[Message]:
    """The good messages of a tlog in file order, each with ``_timestamp`` (record time, seconds since epoch)."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"{p}: no such telemetry log")
    try:
        conn = mavutil.mavlink_connection(str(p), dialect="ardupilotmega", notimestamps=False)
    except OSError as err:
        raise MerlionError(f"{p}: cannot read ({err.strerror or err})") from None
    try:
        while True:
            msg = conn.recv_msg()
            if msg is None:
                return
            if msg.get_type() != "BAD_DATA":
                yield msg
    finally:
        conn.close()


def log_span(path: str | Path) -> tuple[float, float]:
    """First and last record time of a tlog (one streaming pass); MerlionError when it holds no MAVLink."""
    first = last = None
    for msg in stream_tlog(path):
        t = msg._timestamp
        first = t if first is None else first
        last = t
    if first is None:
        raise MerlionError(f"{path}: not a MAVLink telemetry log (.tlog): no valid record found")
    return first, last


class LogLink:
    """The part of ``vehicle.link.MavLink`` that ``VehicleTelemetry`` listens through, fed from a log."""

    def __init__(self) -> None:
        self.autopilot: tuple[int, int] | None = None
        self.autopilot_alive = False
        self._subs: list[tuple[Callable[[Message], None], frozenset[str] | None]] = []
        self._autopilot_cbs: list[Callable[[bool], None]] = []

    def subscribe(self, callback: Callable[[Message], None],
                  types: Iterable[str] | None = None) -> Callable[[], None]:
        entry = (callback, frozenset(types) if types is not None else None)
        self._subs.append(entry)
        return lambda: self._subs.remove(entry)

    def on_autopilot(self, callback: Callable[[bool], None]) -> None:
        self._autopilot_cbs.append(callback)

    def dispatch(self, msg: Message) -> None:
        if self.autopilot is None and is_autopilot_heartbeat(msg):
            self.autopilot = (msg.get_srcSystem(), msg.get_srcComponent())
            self.autopilot_alive = True
            for cb in self._autopilot_cbs:
                cb(True)
        mtype = msg.get_type()
        for callback, types in list(self._subs):
            if types is None or mtype in types:
                callback(msg)


def poses_at(path: str | Path, times: Sequence[float], cfg: TelemetryConfig) -> list[Pose]:
    """The pose at each wall-clock time in ``times`` (any order), interpolated from the log at ``path``.

    A time the log does not cover (or covers only with samples older than ``cfg.stale_after_s``) gets a stale
    pose, never a made-up one.
    """
    order = sorted(range(len(times)), key=lambda i: times[i])
    out: list[Pose | None] = [None] * len(times)
    if not order:
        return []
    now = [-math.inf]
    link = LogLink()
    telemetry = VehicleTelemetry(link, cfg, clock=lambda: now[0], request_rates=False)  # type: ignore[arg-type]
    telemetry.start()
    lead = cfg.stale_after_s + 1.0  # a pose is read once the log is this far past it: every neighbour is in
    skip_before = times[order[0]] - cfg.history_s  # nothing older can matter (the boot clock needs only recent)
    nxt = 0
    for msg in stream_tlog(path):
        t = msg._timestamp
        while nxt < len(order) and t > times[order[nxt]] + lead:
            out[order[nxt]] = telemetry.pose_at(times[order[nxt]])
            nxt += 1
        if nxt == len(order):
            break
        if t >= skip_before or msg.get_type() == "HEARTBEAT":
            now[0] = t
            link.dispatch(msg)
    for i in order[nxt:]:
        out[i] = telemetry.pose_at(times[i])
    telemetry.stop()
    return [p for p in out if p is not None]
