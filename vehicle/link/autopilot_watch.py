"""Which peer on the link is the autopilot, and whether its heartbeat is current.

The identity is settled once, from the first autopilot heartbeat the link lets through, and a stranger's HEARTBEAT
never moves it. With a signing key the link lets through only signed ones (``LinkSigning.require_signed_autopilot``),
so an unsigned heartbeat never settles it nor keeps it alive; with ``mavlink.unsigned_autopilot`` an unsigned first
one is provisional until a signed one arrives. Found and lost are decided on one
thread (the link's timer thread) from the heartbeats the receive thread hands over, so they are reported in the
order they happened and a late "lost" can never overwrite a "found".
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

log = logging.getLogger(__name__)

MAVLinkMessage = mavlink2.MAVLink_message
Source = tuple[int, int]

# Heartbeats of these types are never the autopilot, whatever their ``autopilot`` field says.
_NOT_AUTOPILOT_TYPES = frozenset({
    mavlink2.MAV_TYPE_GCS,
    mavlink2.MAV_TYPE_CAMERA,
    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
    mavlink2.MAV_TYPE_GIMBAL,
    mavlink2.MAV_TYPE_ADSB,
})
_GCS_SYSTEM = 255


def is_autopilot_heartbeat(msg: MAVLinkMessage) -> bool:
    """The autopilot is a submarine, or anything with a real autopilot that is not a GCS, camera or computer."""
    if msg.get_type() != "HEARTBEAT":
        return False
    if msg.type == mavlink2.MAV_TYPE_SUBMARINE:
        return True
    return msg.type not in _NOT_AUTOPILOT_TYPES and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID


class AutopilotWatch:
    """The autopilot's identity (written on the receive thread) and liveness (written on the timer thread)."""

    def __init__(self, *, name: str, clock: Callable[[], float], timeout_s: float,
                 on_adopt: Callable[[Source], None]) -> None:
        self.name = name
        self.clock = clock
        self.timeout_s = timeout_s
        self._on_adopt = on_adopt
        self.autopilot: Source | None = None
        self.alive = False
        self.last_heartbeat: MAVLinkMessage | None = None
        self.foreign_heartbeats = 0
        """Autopilot heartbeats from another system or component than the autopilot found first: ignored."""
        self._signed = False
        self._last_seen: float | None = None
        self._heard: queue.SimpleQueue[float] = queue.SimpleQueue()
        self._found = threading.Event()
        self._callbacks: list[Callable[[bool], None]] = []

    def on_change(self, callback: Callable[[bool], None]) -> None:
        """``callback(True)`` when found (again), ``callback(False)`` when lost; on the watching thread, in order."""
        self._callbacks.append(callback)

    def wait_found(self, timeout: float) -> bool:
        return self._found.wait(timeout)

    def heard(self, msg: MAVLinkMessage) -> bool:
        """Take an autopilot heartbeat (on the receive thread, after signing admitted it). False: a stranger's
        heartbeat, which subscribers still see but telemetry does not take."""
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src[0] == _GCS_SYSTEM:
            return False
        signed = bool(getattr(msg, "_signed", False))
        if self.autopilot is None or (src != self.autopilot and signed and not self._signed):
            self._adopt(src, signed)
        elif src != self.autopilot:
            self.foreign_heartbeats += 1
            if self.foreign_heartbeats == 1:
                log.warning("%s: autopilot heartbeat from %d/%d ignored: the autopilot is %d/%d", self.name, *src,
                            *self.autopilot)
            return False
        elif signed:
            self._signed = True
        self.last_heartbeat = msg
        self._heard.put(self.clock())  # the watching thread says "found", not this one
        return True

    def watch(self, poll_s: float) -> None:
        """Wait up to ``poll_s`` for heartbeats heard, then declare the autopilot found or lost (the one writer of
        ``alive``): a heartbeat heard while a loss is declared is reported as found after it, never lost after."""
        heard = None
        try:
            heard = self._heard.get(timeout=poll_s)
            while True:
                heard = self._heard.get_nowait()
        except queue.Empty:
            pass
        if heard is not None:
            self._last_seen = heard
            if not self.alive:
                self.alive = True
                self._found.set()
                log.info("%s: autopilot %d/%d found", self.name, *(self.autopilot or (0, 0)))
                self._notify(True)
            return
        seen = self._last_seen
        now = self.clock()
        if self.alive and seen is not None and now - seen > self.timeout_s:
            self.alive = False
            self._found.clear()
            log.warning("%s: autopilot heartbeat lost (%.1f s)", self.name, now - seen)
            self._notify(False)

    def _adopt(self, src: Source, signed: bool) -> None:
        if self.autopilot is not None:
            log.warning("%s: autopilot %d/%d signs: it replaces %d/%d, whose heartbeat was unsigned", self.name,
                        *src, *self.autopilot)
        self.autopilot = src
        self._signed = signed
        self._on_adopt(src)

    def _notify(self, alive: bool) -> None:
        for callback in list(self._callbacks):
            try:
                callback(alive)
            except Exception:
                log.exception("%s: autopilot callback failed", self.name)
