"""A simulated ArduSub autopilot on the wire: the telemetry, rates and commands the companion relies on.

It speaks through the same ``MavLink`` as the companion (system 1, component 1), follows a scripted dive
(``vehicle.sim.dive_profile``), streams ArduSub's usual messages at ArduSub-like default rates, honours
MAV_CMD_SET_MESSAGE_INTERVAL / MAV_CMD_GET_MESSAGE_INTERVAL / MAV_CMD_REQUEST_MESSAGE with a COMMAND_ACK and
the legacy REQUEST_DATA_STREAM (no ACK, as on ArduPilot), and can go silent or reboot (its boot time restarts)
so that loss handling can be exercised. ``SimVehicle`` runs in-thread for tests; ``merlion sim-vehicle`` runs
it as a separate process.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.autopilot.pose_history import euler_to_quaternion
from vehicle.link.connection import MavLink
from vehicle.settings import MavlinkConfig
from vehicle.sim.dive_profile import DiveProfile, VehicleState, load_profile

log = logging.getLogger(__name__)

GRAVITY = 9.80665
_MODE_NUMBERS = {name: number for number, name in mavutil.mode_mapping_sub.items()}

# Messages the simulator can produce, and ArduSub-like default rates in Hz (0: only when asked for).
DEFAULT_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "SYSTEM_TIME": 1.0,
    "ATTITUDE": 10.0,
    "ATTITUDE_QUATERNION": 0.0,
    "GLOBAL_POSITION_INT": 3.0,
    "LOCAL_POSITION_NED": 3.0,
    "VFR_HUD": 4.0,
    "SCALED_PRESSURE2": 2.0,
    "BATTERY_STATUS": 1.0,
}
# REQUEST_DATA_STREAM groups, as ArduSub assigns these messages to them.
DATA_STREAMS: dict[int, tuple[str, ...]] = {
    mav2.MAV_DATA_STREAM_RAW_SENSORS: ("SCALED_PRESSURE2",),
    mav2.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS",),
    mav2.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mav2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    mav2.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    mav2.MAV_DATA_STREAM_EXTRA3: ("SYSTEM_TIME", "BATTERY_STATUS"),
}
_IDS = {name: getattr(mav2, f"MAVLINK_MSG_ID_{name}") for name in DEFAULT_RATES}
_NAMES = {msg_id: name for name, msg_id in _IDS.items()}


class SimVehicle:
    """ArduSub on the wire, in a thread; ``start``/``stop``, ``silence(s)`` and ``reboot()`` at any time."""

    def __init__(
        self,
        connection: str,
        profile: DiveProfile | None = None,
        *,
        system_id: int = 1,
        rates: dict[str, float] | None = None,
        message_interval: bool = True,
        fluid_density: float = 1025.0,
        surface_pressure_hpa: float = 1013.25,
        reboot_s: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        signing_key_file: str | None = None,
    ) -> None:
        unknown = set(rates or {}) - set(DEFAULT_RATES)
        if unknown:
            raise ValueError(f"sim vehicle cannot send {sorted(unknown)[0]}")
        self.profile = profile or load_profile(None)
        self.defaults = {**DEFAULT_RATES, **(rates or {})}
        self.message_interval = message_interval
        self.fluid_density = fluid_density
        self.surface_pressure_hpa = surface_pressure_hpa
        self.reboot_s = reboot_s
        self.clock = clock
        self.wall_clock = wall_clock
        self.link = MavLink(connection, MavlinkConfig(system_id=system_id, component_id=1,
                                                      signing_key_file=signing_key_file),
                            clock=clock, name="sim-ardusub", heartbeat=False)
        self.link.subscribe(self._on_setup_signing, ["SETUP_SIGNING"])
        self.link.subscribe(self._on_command, ["COMMAND_LONG", "REQUEST_DATA_STREAM"])
        self.sent: dict[str, int] = dict.fromkeys(DEFAULT_RATES, 0)
        self.reboots = 0
        self.commands: list[tuple[int, float, float, int]] = []
        """(command, param1, param2, result) of every COMMAND_LONG handled, for tests and logs."""
        self.data_stream_requests: list[tuple[int, int, int]] = []
        self._lock = threading.Lock()
        self._start = clock()
        self._boot = self._start
        self._silent_until = 0.0
        self._intervals: dict[str, float | None] = {}
        self._due: dict[str, float] = {}
        self._reset_rates()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------------------------ signing
    def _on_setup_signing(self, msg: mav2.MAVLink_message) -> None:
        """SETUP_SIGNING as ArduSub takes it: a new key (all zeros: signing off). The link only lets it through
        unsigned while no key is set; once one is, it must come signed with that key, like any write."""
        if msg.target_system not in (0, self.link.system_id):
            return
        self.link.signing.set_key(bytes(msg.secret_key), msg.initial_timestamp)
        log.info("sim-ardusub: signing %s by %d/%d", "on" if self.link.signing.enabled else "off",
                 msg.get_srcSystem(), msg.get_srcComponent())

    # ------------------------------------------------------------------------------------------ control
    def start(self) -> None:
        self._start = self._boot = self.clock()
        self.link.start()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-ardusub", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.link.stop()

    def __enter__(self) -> SimVehicle:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def silence(self, seconds: float) -> None:
        """Send nothing and answer nothing for ``seconds`` (a cable fault, a busy router)."""
        with self._lock:
            self._silent_until = max(self._silent_until, self.clock() + seconds)
        log.info("sim-ardusub: silent for %.1f s", seconds)

    def reboot(self) -> None:
        """Go silent for ``reboot_s``, then come back with boot time restarted and default rates."""
        with self._lock:
            now = self.clock()
            self._silent_until = max(self._silent_until, now + self.reboot_s)
            self._boot = now + self.reboot_s
            self.reboots += 1
            self._reset_rates(start=now + self.reboot_s)
        log.info("sim-ardusub: rebooting (back in %.1f s)", self.reboot_s)

    @property
    def silent(self) -> bool:
        return self.clock() < self._silent_until

    def time_boot_ms(self) -> int:
        return max(0, int((self.clock() - self._boot) * 1000))

    def set_rate(self, name: str, hz: float) -> None:
        """Change a message rate from outside, as a ground station's SET_MESSAGE_INTERVAL would (0: off)."""
        if name not in self._intervals:
            raise ValueError(f"sim vehicle cannot send {name}")
        self._set_interval(name, 1.0 / hz if hz > 0 else None)

    def interval(self, name: str) -> float | None:
        """The current interval of a message in seconds (None: not sent)."""
        with self._lock:
            return self._intervals.get(name)

    def state(self) -> VehicleState:
        return self.profile.state(self.clock() - self._start)

    # ------------------------------------------------------------------------------------------ streaming
    def _reset_rates(self, start: float | None = None) -> None:
        start = self.clock() if start is None else start
        self._intervals = {n: (1.0 / hz if hz > 0 else None) for n, hz in self.defaults.items()}
        self._due = {n: start for n in self._intervals}

    def _set_interval(self, name: str, interval: float | None) -> None:
        with self._lock:
            self._intervals[name] = interval
            self._due[name] = self.clock()

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            now = self.clock()
            if self.silent:
                continue
            with self._lock:
                due = [n for n, iv in self._intervals.items() if iv is not None and now >= self._due[n]]
                for n in due:
                    iv = self._intervals[n]
                    nxt = self._due[n] + iv
                    self._due[n] = nxt if nxt > now else now + iv
            for name in due:
                self._emit(name)

    def _emit(self, name: str) -> None:
        msg = self.build(name)
        if self.link.send(msg):
            self.sent[name] += 1

    def build(self, name: str) -> mav2.MAVLink_message:
        """One message of the kind ``name`` describing the vehicle now."""
        s = self.state()
        boot_ms = self.time_boot_ms()
        heading = math.degrees(s.yaw) % 360.0
        if name == "HEARTBEAT":
            base = mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav2.MAV_MODE_FLAG_STABILIZE_ENABLED
            if s.armed:
                base |= mav2.MAV_MODE_FLAG_SAFETY_ARMED
            return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                                                  _MODE_NUMBERS.get(s.mode, 19), mav2.MAV_STATE_ACTIVE, 3)
        if name == "SYSTEM_TIME":
            return mav2.MAVLink_system_time_message(int(self.wall_clock() * 1e6), boot_ms)
        if name == "ATTITUDE":
            return mav2.MAVLink_attitude_message(boot_ms, s.roll, s.pitch, _wrap_pi(s.yaw), 0.0, 0.0, 0.0)
        if name == "ATTITUDE_QUATERNION":
            w, x, y, z = euler_to_quaternion(s.roll, s.pitch, s.yaw)
            return mav2.MAVLink_attitude_quaternion_message(boot_ms, w, x, y, z, 0.0, 0.0, 0.0, [0.0] * 4)
        if name == "GLOBAL_POSITION_INT":
            lat = int(round(s.lat * 1e7)) if s.lat is not None else 0
            lon = int(round(s.lon * 1e7)) if s.lon is not None else 0
            alt = int(round(s.alt_m * 1000)) if s.alt_m is not None else 0
            return mav2.MAVLink_global_position_int_message(
                boot_ms, lat, lon, alt, int(round(-s.depth * 1000)), _cms(s.vn), _cms(s.ve), _cms(s.vd),
                int(round(heading * 100)) % 36000)
        if name == "LOCAL_POSITION_NED":
            return mav2.MAVLink_local_position_ned_message(boot_ms, s.north, s.east, s.depth, s.vn, s.ve, s.vd)
        if name == "VFR_HUD":
            alt = -s.depth if self.profile.origin is not None else 0.0  # 0 without an EKF origin, as on ArduSub
            return mav2.MAVLink_vfr_hud_message(0.0, math.hypot(s.vn, s.ve), int(heading), 0, alt, -s.vd)
        if name == "SCALED_PRESSURE2":
            press = self.surface_pressure_hpa + self.fluid_density * GRAVITY * s.depth / 100.0
            return mav2.MAVLink_scaled_pressure2_message(boot_ms, press, 0.0, 1500, 0)
        remaining = max(0, 100 - int((self.clock() - self._start) / 60))
        volts = 12.8 + 3.2 * remaining / 100
        if name == "SYS_STATUS":
            return mav2.MAVLink_sys_status_message(0, 0, 0, 200, int(volts * 1000), 850, remaining, 0, 0, 0, 0, 0, 0)
        if name == "BATTERY_STATUS":
            cells = [int(volts * 1000)] + [65535] * 9
            return mav2.MAVLink_battery_status_message(0, 0, 0, 2500, cells, 850, -1, -1, remaining)
        raise ValueError(f"sim vehicle cannot send {name}")

    # ------------------------------------------------------------------------------------------ commands
    def _for_us(self, target_system: int, target_component: int) -> bool:
        return target_system in (0, self.link.system_id) and target_component in (0, self.link.component_id)

    def _on_command(self, msg: mav2.MAVLink_message) -> None:
        if self.silent or not self._for_us(msg.target_system, msg.target_component):
            return
        if msg.get_type() == "REQUEST_DATA_STREAM":
            self._data_stream(msg)
            return
        result = self._command(msg)
        self.commands.append((msg.command, msg.param1, msg.param2, result))
        self.link.send(mav2.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(),
                                                        msg.get_srcComponent()))
        if msg.command == mav2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and result == mav2.MAV_RESULT_ACCEPTED:
            self.reboot()

    def _command(self, msg: mav2.MAVLink_message) -> int:
        cmd, p1, p2 = msg.command, msg.param1, msg.param2
        name = _NAMES.get(int(p1)) if math.isfinite(p1) else None
        if cmd == mav2.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not self.message_interval:
                return mav2.MAV_RESULT_UNSUPPORTED
            if name is None or not math.isfinite(p2):
                return mav2.MAV_RESULT_DENIED
            if p2 < 0:
                self._set_interval(name, None)
            elif p2 == 0:
                hz = self.defaults[name]
                self._set_interval(name, 1.0 / hz if hz > 0 else None)
            else:
                self._set_interval(name, p2 / 1e6)
            return mav2.MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_GET_MESSAGE_INTERVAL:
            if not self.message_interval:
                return mav2.MAV_RESULT_UNSUPPORTED
            if name is None:
                return mav2.MAV_RESULT_DENIED
            iv = self.interval(name)
            self.link.send(mav2.MAVLink_message_interval_message(int(p1), -1 if iv is None else int(iv * 1e6)))
            return mav2.MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_REQUEST_MESSAGE:
            if name is None:
                return mav2.MAV_RESULT_DENIED
            self._emit(name)
            return mav2.MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            return mav2.MAV_RESULT_ACCEPTED if p1 == 1 else mav2.MAV_RESULT_UNSUPPORTED
        return mav2.MAV_RESULT_UNSUPPORTED

    def _data_stream(self, msg: mav2.MAVLink_message) -> None:
        self.data_stream_requests.append((msg.req_stream_id, msg.req_message_rate, msg.start_stop))
        if msg.req_stream_id == mav2.MAV_DATA_STREAM_ALL:
            names = [n for group in DATA_STREAMS.values() for n in group]
        else:
            names = list(DATA_STREAMS.get(msg.req_stream_id, ()))
        on = msg.start_stop and msg.req_message_rate > 0
        for name in names:
            self._set_interval(name, 1.0 / msg.req_message_rate if on else None)


def _cms(v: float) -> int:
    return int(round(v * 100))


def _wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def run_sim_vehicle(
    sim: SimVehicle,
    *,
    duration: float | None = None,
    silence_at: float | None = None,
    silence_for: float = 5.0,
    reboot_at: float | None = None,
    stop: threading.Event | None = None,
    report: Callable[[str], None] | None = None,
    report_every_s: float = 10.0,
) -> dict[str, object]:
    """Run ``sim`` until ``duration`` or ``stop``, going silent / rebooting at the scheduled times (seconds after
    start); returns counters. The command line adds signals (SIGUSR1: silence, SIGUSR2: reboot) on top."""
    stop = stop or threading.Event()
    events = sorted(
        [(t, "silence") for t in ([silence_at] if silence_at is not None else [])]
        + [(t, "reboot") for t in ([reboot_at] if reboot_at is not None else [])]
    )
    sim.start()
    t0 = sim.clock()
    next_report = report_every_s
    try:
        while not stop.is_set():
            elapsed = sim.clock() - t0
            if duration is not None and elapsed >= duration:
                break
            while events and elapsed >= events[0][0]:
                _, what = events.pop(0)
                if what == "silence":
                    sim.silence(silence_for)
                else:
                    sim.reboot()
            if report is not None and elapsed >= next_report:
                next_report += report_every_s
                s = sim.state()
                report(f"sim-vehicle: t={elapsed:.0f} s depth {s.depth:.2f} m, heading "
                       f"{math.degrees(s.yaw) % 360:.0f} deg, mode {s.mode}{' (silent)' if sim.silent else ''}, "
                       f"sent {sum(sim.sent.values())} messages")
            stop.wait(0.05)
    finally:
        sim.stop()
    return {"sent": dict(sim.sent), "reboots": sim.reboots, "commands": len(sim.commands),
            "data_stream_requests": len(sim.data_stream_requests), "rx_bad": sim.link.rx_bad}
