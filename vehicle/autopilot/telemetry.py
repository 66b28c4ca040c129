"""ArduSub telemetry as the companion needs it: the latest state, and the pose at any frame's capture time.

``VehicleTelemetry(link, cfg.telemetry)`` subscribes to the autopilot's messages on a ``MavLink``, maps their
``time_boot_ms`` to the companion's wall clock (``BootClock``), records depth, attitude, heading and position in a
``PoseHistory`` and asks for the rates it needs (``RateKeeper``). Depth comes from GLOBAL_POSITION_INT.relative_alt
when the autopilot sends it, else from SCALED_PRESSURE2 (with the configured fluid density and surface pressure),
else from VFR_HUD.alt; the source of every sample is recorded. When LOCAL_POSITION_NED never comes (an ArduSub
without a position source: no DVL, no USBL) it is asked for less and less often, and, once the autopilot has been up
``position_wait_s`` (its EKF sets the origin ~16 s after boot), the companion says so once: a log line and a notice
(``on_notice``) the live app turns into one STATUSTEXT. Positions that come after that take it back the same ways.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.autopilot.pose import Pose, wrap_heading
from vehicle.autopilot.pose_history import PoseHistory, euler_to_quaternion, normalise, quaternion_to_euler
from vehicle.link.clock_sync import BootClock
from vehicle.link.connection import MavLink
from vehicle.link.message_rates import RateKeeper
from vehicle.settings import TelemetryConfig

log = logging.getLogger(__name__)

GRAVITY = 9.80665
DEPTH_SOURCES = ("global_position_int", "scaled_pressure2", "vfr_hud")
NO_POSITION_TEXT = "No position source (no DVL/USBL): depth only"
"""The STATUSTEXT that says LOCAL_POSITION_NED never came (once the autopilot had time to set its EKF origin)."""
POSITION_FOUND_TEXT = "Position source found: positions arrive now"
"""The STATUSTEXT that takes NO_POSITION_TEXT back when LOCAL_POSITION_NED starts arriving after it was sent."""
_TYPES = ("HEARTBEAT", "SYSTEM_TIME", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT",
          "LOCAL_POSITION_NED", "SCALED_PRESSURE2", "VFR_HUD", "SYS_STATUS", "BATTERY_STATUS")


@dataclass(frozen=True)
class TelemetrySnapshot:
    """The newest value of everything, for status reports and the live display (None: never received)."""

    time: float | None = None
    depth_m: float | None = None
    depth_source: str | None = None
    roll: float | None = None
    pitch: float | None = None
    yaw: float | None = None
    heading_deg: float | None = None
    lat: float | None = None
    lon: float | None = None
    north_m: float | None = None
    east_m: float | None = None
    down_m: float | None = None
    armed: bool | None = None
    mode: str | None = None
    battery_v: float | None = None
    battery_pct: int | None = None
    autopilot_alive: bool = False
    autopilot_utc: float | None = None
    """The autopilot's own UTC (SYSTEM_TIME), when it has one."""
    clock_offset_s: float | None = None
    autopilot_reboots: int = 0
    position_source: bool | None = None
    """False once LOCAL_POSITION_NED was asked for and never came, the autopilot up ``position_wait_s`` (no DVL/USBL);
    True once it came (again: a later arrival clears the False, and says so)."""
    spoofed_ignored: int = 0
    """Unsigned messages claiming to be the autopilot after it was seen signing: ignored (docs/security.md)."""

    def to_dict(self) -> dict:
        return asdict(self)


def depth_from_pressure(press_abs_hpa: float, fluid_density: float, surface_pressure_hpa: float) -> float:
    """Metres below the surface from absolute pressure: (p - p_surface) / (rho g)."""
    return (press_abs_hpa - surface_pressure_hpa) * 100.0 / (fluid_density * GRAVITY)


class VehicleTelemetry:
    """Attach to a link with ``start()``; read ``latest`` and ``pose_at(t)`` from any thread."""

    def __init__(self, link: MavLink, cfg: TelemetryConfig, *, clock: Callable[[], float] = time.time,
                 request_rates: bool = True, rate_clock: Callable[[], float] = time.monotonic,
                 rate_options: dict[str, Any] | None = None) -> None:
        """``rate_options``: RateKeeper settings (grace_s, backoff_max_s, missing_after, ...) for tools and tests."""
        self.link = link
        self.cfg = cfg
        self.clock = clock
        self.boot_clock = BootClock()
        self.history = PoseHistory(cfg.stale_after_s, cfg.history_s)
        self.rates = RateKeeper(link, self.wanted_rates(cfg), clock=rate_clock, on_missing=self._on_missing,
                                **{"grace_s": cfg.rate_grace_s, "listen_s": cfg.rate_listen_s,
                                   **(rate_options or {})}) if request_rates else None
        self._notices: list[Callable[[str, int], None]] = []
        self.messages = 0
        self._lock = threading.Lock()
        self._latest = TelemetrySnapshot()
        self._depth_seen: dict[str, float] = {}
        self._unsubscribe: Callable[[], None] | None = None
        self._changed = threading.Condition()
        self._position_missing = False
        """The rate keeper gave up waiting for LOCAL_POSITION_NED; said once the autopilot is up long enough."""
        self._uptime_s: float | None = None
        """The autopilot's newest time_boot_ms, in seconds."""
        self._first_heard: float | None = None
        """When the autopilot was first heard (monotonic): its uptime's floor when it sends no time_boot_ms."""
        self._boot_epoch_s: float | None = None
        """The autopilot's UTC at its boot (SYSTEM_TIME.time_unix_usec - time_boot_ms), once it has UTC."""

    @staticmethod
    def wanted_rates(cfg: TelemetryConfig) -> dict[str, float]:
        return {
            "ATTITUDE": cfg.attitude_hz,
            "ATTITUDE_QUATERNION": cfg.attitude_hz,
            "GLOBAL_POSITION_INT": cfg.position_hz,
            "LOCAL_POSITION_NED": cfg.position_hz,
            "SCALED_PRESSURE2": cfg.pressure_hz,
            "SYSTEM_TIME": 1.0,
        }

    def start(self) -> None:
        """Subscribe to the link (which may already be running) and start asking for rates."""
        self._unsubscribe = self.link.subscribe(self._on_message, _TYPES)
        self.link.on_autopilot(self._on_autopilot)
        if self.rates is not None:
            self.rates.start()

    def stop(self) -> None:
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        if self.rates is not None:
            self.rates.stop()

    def on_notice(self, callback: Callable[[str, int], None]) -> None:
        """``callback(text, severity)`` for news worth one STATUSTEXT (text <= 50 characters, MAV_SEVERITY_*)."""
        self._notices.append(callback)

    @property
    def latest(self) -> TelemetrySnapshot:
        with self._lock:
            return replace(self._latest, autopilot_alive=self.link.autopilot_alive,
                           spoofed_ignored=sum(self.link.signing.spoofed.values()),
                           clock_offset_s=self.boot_clock.offset, autopilot_reboots=self.boot_clock.reboots)

    def pose_at(self, t: float) -> Pose:
        """The pose at companion wall-clock time ``t`` (a frame's ``capture_time``); stale when nothing is near.

        The history is kept in the autopilot's own time (seconds since boot), so a better clock estimate later
        moves every sample together; ``t`` is mapped into that time line with the current estimate.
        """
        offset = self.boot_clock.offset
        if offset is None:
            return Pose(time=t, age_s=math.inf, stale=True)
        boot_s = t - offset
        epoch = self._boot_epoch_s
        return replace(self.history.pose_at(boot_s), time=t, time_boot_ms=max(0, round(boot_s * 1000.0)),
                       autopilot_unix_usec=None if epoch is None else round((epoch + boot_s) * 1e6))

    def wait_for(self, predicate: Callable[[TelemetrySnapshot], bool], timeout: float) -> bool:
        """Block until ``predicate(latest)`` holds (for start-up, tools and tests)."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while not predicate(self.latest):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._changed.wait(min(left, 0.2))
        return True

    # ------------------------------------------------------------------------------------------ internals
    def _on_autopilot(self, alive: bool) -> None:
        with self._changed:
            self._changed.notify_all()

    def _on_missing(self, name: str) -> None:
        """RateKeeper gave up expecting ``name`` (on its thread, once per declaration)."""
        if self.link.signing.mismatch:  # our requests never reached it: the autopilot is not to blame
            log.warning("%s never came: the autopilot %s and ignores this companion's rate requests", name,
                        self.link.signing.autopilot)
            return
        if name != "LOCAL_POSITION_NED":
            log.warning("the autopilot never sends %s, asked for %d times", name, self.rates.requests[name]
                        if self.rates is not None else 0)
            return
        self._position_missing = True
        self._maybe_no_position()

    def _maybe_no_position(self) -> None:
        """Say there is no position source, once, when LOCAL_POSITION_NED was given up on and the autopilot has been
        up ``position_wait_s``: before that its EKF may simply not have its origin yet (~16 s after boot in
        ArduSub SITL), and the positions start by themselves."""
        if not self._position_missing:
            return
        uptime = self._uptime_s
        if uptime is None:
            uptime = 0.0 if self._first_heard is None else time.monotonic() - self._first_heard
        if uptime < self.cfg.position_wait_s:
            return
        with self._lock:
            if self._latest.position_source is not None or not self._position_missing:
                return  # said once already, or the positions came meanwhile
            self._latest = replace(self._latest, position_source=False)
        log.warning("no position source: the autopilot never sends LOCAL_POSITION_NED (no DVL or USBL), up %.0f s; "
                    "frames carry depth and attitude only", uptime)
        for notify in self._notices:
            notify(NO_POSITION_TEXT, mav2.MAV_SEVERITY_INFO)

    def _position_found(self) -> None:
        """LOCAL_POSITION_NED arrives after "no position source" was said: take it back, in the log and the notice."""
        log.warning("position source found: LOCAL_POSITION_NED arrives now; frames carry position")
        for notify in self._notices:
            notify(POSITION_FOUND_TEXT, mav2.MAV_SEVERITY_INFO)

    def _sample_time(self, msg: mav2.MAVLink_message, arrival: float) -> float | None:
        """When the autopilot measured ``msg``, in its seconds since boot (None: not placeable yet)."""
        boot_ms = getattr(msg, "time_boot_ms", None)
        if boot_ms is None:  # VFR_HUD and friends carry no time: place them at arrival, mapped back
            offset = self.boot_clock.offset
            return None if offset is None else arrival - offset
        self._uptime_s = boot_ms / 1000.0
        if self.boot_clock.observe(boot_ms, arrival):
            log.warning("autopilot rebooted (time_boot_ms went back to %d): time mapping restarted", boot_ms)
            self.history.clear()
            self._boot_epoch_s = None  # the new boot's UTC comes with its next SYSTEM_TIME
        return boot_ms / 1000.0

    def _on_message(self, msg: mav2.MAVLink_message) -> None:
        if self.link.autopilot is None or (msg.get_srcSystem(), msg.get_srcComponent()) != self.link.autopilot:
            return  # only the autopilot's telemetry (a GCS or replayed camera says nothing about the vehicle)
        arrival = self.clock()
        if self._first_heard is None:
            self._first_heard = time.monotonic()
        t = self._sample_time(msg, arrival)
        mtype = msg.get_type()
        update: dict = {}
        h = self.history if t is not None else None  # None: cannot be placed in time yet, state only
        if mtype == "HEARTBEAT":
            update["armed"] = bool(msg.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED)
            update["mode"] = mavutil.mode_mapping_sub.get(msg.custom_mode, f"MODE{msg.custom_mode}")
        elif mtype == "SYSTEM_TIME":
            if msg.time_unix_usec > 0:
                update["autopilot_utc"] = msg.time_unix_usec / 1e6
                self._boot_epoch_s = msg.time_unix_usec / 1e6 - msg.time_boot_ms / 1000.0
        elif mtype == "ATTITUDE":
            q = euler_to_quaternion(msg.roll, msg.pitch, msg.yaw)
            if h is not None:
                h.add_attitude(t, q)
            update.update(roll=msg.roll, pitch=msg.pitch, yaw=msg.yaw, heading_deg=wrap_heading(math.degrees(msg.yaw)))
        elif mtype == "ATTITUDE_QUATERNION":
            try:
                q = normalise((msg.q1, msg.q2, msg.q3, msg.q4))
            except ValueError:
                return  # all zeros (not initialised yet) or NaN: nothing to record
            if h is not None:
                h.add_attitude(t, q)
            roll, pitch, yaw = quaternion_to_euler(q)
            update.update(roll=roll, pitch=pitch, yaw=yaw, heading_deg=wrap_heading(math.degrees(yaw)))
        elif mtype == "GLOBAL_POSITION_INT":
            self._depth(update, t, arrival, "global_position_int", -msg.relative_alt / 1000.0, msg.vz / 100.0)
            if msg.hdg != 65535 and h is not None:
                h.add_heading(t, msg.hdg / 100.0)
            if msg.lat != 0 or msg.lon != 0:  # 0/0 means the EKF has no origin
                lat, lon = msg.lat / 1e7, msg.lon / 1e7
                if h is not None:
                    h.add_global_position(t, lat, lon, msg.alt / 1000.0)
                update.update(lat=lat, lon=lon)
        elif mtype == "SCALED_PRESSURE2":
            depth = depth_from_pressure(msg.press_abs, self.cfg.fluid_density, self.cfg.surface_pressure_hpa)
            self._depth(update, t, arrival, "scaled_pressure2", depth)
            if h is not None:  # the Bar30's water temperature and pressure ride along on every frame's pose
                h.add_water(t, msg.press_abs, msg.temperature / 100.0)
        elif mtype == "VFR_HUD":
            self._depth(update, t, arrival, "vfr_hud", -msg.alt)
            if h is not None:
                h.add_heading(t, float(msg.heading))
        elif mtype == "LOCAL_POSITION_NED":
            if h is not None:
                h.add_local_position(t, msg.x, msg.y, msg.z)
            update.update(north_m=msg.x, east_m=msg.y, down_m=msg.z, position_source=True)
        elif mtype == "SYS_STATUS":
            if msg.voltage_battery != 65535:
                update["battery_v"] = msg.voltage_battery / 1000.0
            if msg.battery_remaining >= 0:
                update["battery_pct"] = msg.battery_remaining
        elif mtype == "BATTERY_STATUS":
            cells = [v for v in msg.voltages if v != 65535]
            if cells:
                update["battery_v"] = sum(cells) / 1000.0
            if msg.battery_remaining >= 0:
                update["battery_pct"] = msg.battery_remaining
        found = False
        with self._changed:
            with self._lock:
                self.messages += 1
                if mtype == "LOCAL_POSITION_NED":
                    found = self._latest.position_source is False  # said missing: now it is not
                    self._position_missing = False
                self._latest = replace(self._latest, time=arrival, **update)
            self._changed.notify_all()
        if found:
            self._position_found()
        elif self._position_missing:
            self._maybe_no_position()

    def _depth(self, update: dict, t: float | None, arrival: float, source: str, depth: float,
               rate_mps: float | None = None) -> None:
        """Record depth from ``source`` unless a better source has spoken within the stale limit."""
        self._depth_seen[source] = arrival
        rank = DEPTH_SOURCES.index(source)
        for better in DEPTH_SOURCES[:rank]:
            seen = self._depth_seen.get(better)
            if seen is not None and arrival - seen <= max(self.cfg.stale_after_s, 2.0):
                return
        if source == "vfr_hud" and depth == 0.0 and self._latest.lat is None:
            return  # VFR_HUD.alt is 0 without an EKF origin: no information
        if t is not None:
            self.history.add_depth(t, depth, source, rate_mps)
        update.update(depth_m=depth, depth_source=source)

