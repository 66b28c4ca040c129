"""A simulated ArduSub autopilot on the wire: the telemetry, rates, commands and failsafes the companion meets.

It speaks through the same ``MavLink`` as the companion (system 1, component 1), follows a scripted dive
(``vehicle.sim.dive_profile``) and behaves as ArduPilot's ArduSub firmware was measured to (``REFERENCE.md``,
"What the real ArduSub firmware does"):

- default streams with no request: ATTITUDE and VFR_HUD 10 Hz, GLOBAL_POSITION_INT 3.2 Hz, SYS_STATUS,
  SCALED_PRESSURE, SCALED_PRESSURE2 and HEARTBEAT 1 Hz; MAV_CMD_SET_MESSAGE_INTERVAL / GET_MESSAGE_INTERVAL /
  REQUEST_MESSAGE answered with a COMMAND_ACK, the legacy REQUEST_DATA_STREAM without one; the simulator has one
  link, so the last request from any peer wins for every listener, as on a router in front of one serial port;
- ``relative_alt`` valid from boot; VFR_HUD.alt, GLOBAL_POSITION_INT lat/lon/alt and LOCAL_POSITION_NED only
  once the EKF has an origin (``origin.after_s`` after boot, never without a position source unless a ground
  station sends SET_GPS_GLOBAL_ORIGIN);
- the parameters it acts on, served with the parameter protocol (``vehicle.sim.params``): FS_PILOT_INPUT,
  FS_PILOT_TIMEOUT, FS_GCS_ENABLE, FS_GCS_TIMEOUT, MAV_GCS_SYSID, PILOT_SPEED_UP/DN, with the firmware's defaults;
- MANUAL_CONTROL counts only from system ``MAV_GCS_SYSID`` (255) and with ``target`` = this vehicle, and it counts
  as that ground station's heartbeat too; anyone else's is ignored (but recorded);
- the pilot-input and GCS failsafes, in ``vehicle.sim.failsafes`` (told what the vehicle hears, checked each tick);
  each failsafe that acts is recorded in ``failsafes``, and every peer's heartbeat ids and MANUAL_CONTROL senders
  are recorded, so that tests can prove the companion never takes part in either;
- MANUAL_CONTROL flies the vehicle (the pilot takes over from the script): ``z`` below 500 descends (up to
  PILOT_SPEED_DN, or PILOT_SPEED_UP when that is 0), above ascends (up to PILOT_SPEED_UP, 1 m/s), 500 holds depth
  (ALT_HOLD). Arm/disarm and mode changes by command.

It can also go silent or reboot (its boot time restarts) so that loss handling can be exercised. ``SimVehicle``
runs in-thread for tests; ``merlion sim-vehicle`` runs it as a separate process.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.link.connection import MavLink
from vehicle.settings import MavlinkConfig
from vehicle.sim.dive_profile import DiveProfile, Origin, VehicleState, load_profile
from vehicle.sim.failsafes import Failsafes
from vehicle.sim.messages import Moment, build_message
from vehicle.sim.params import GCS_FAILSAFE_ACTIONS, SimParams

log = logging.getLogger(__name__)

GCS_SYSID = 255
"""MAV_GCS_SYSID's default: the ground station whose heartbeats arm the GCS failsafe."""
FS_PILOT_TIMEOUT_S = 3.0
FS_GCS_TIMEOUT_S = 5.0

# Messages the simulator can produce, and the real ArduSub's default rates in Hz (0: only when asked for).
DEFAULT_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "SYSTEM_TIME": 0.0,
    "ATTITUDE": 10.0,
    "ATTITUDE_QUATERNION": 0.0,
    "GLOBAL_POSITION_INT": 3.2,
    "LOCAL_POSITION_NED": 3.2,  # same stream as GLOBAL_POSITION_INT, but only sent with an EKF origin
    "VFR_HUD": 10.0,
    "SCALED_PRESSURE": 1.0,
    "SCALED_PRESSURE2": 1.0,
    "BATTERY_STATUS": 0.0,
}
# REQUEST_DATA_STREAM groups, as ArduSub assigns these messages to them.
DATA_STREAMS: dict[int, tuple[str, ...]] = {
    mav2.MAV_DATA_STREAM_RAW_SENSORS: ("SCALED_PRESSURE", "SCALED_PRESSURE2"),
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
        pilot_timeout_s: float = FS_PILOT_TIMEOUT_S,
        gcs_timeout_s: float = FS_GCS_TIMEOUT_S,
        gcs_failsafe: str = "disarm",
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        signing_key_file: str | None = None,
    ) -> None:
        unknown = set(rates or {}) - set(DEFAULT_RATES)
        if unknown:
            raise ValueError(f"sim vehicle cannot send {sorted(unknown)[0]}")
        if gcs_failsafe not in GCS_FAILSAFE_ACTIONS:
            raise ValueError(f"GCS failsafe action must be one of {GCS_FAILSAFE_ACTIONS}, got {gcs_failsafe!r}")
        self.profile = profile or load_profile(None)
        self.defaults = {**DEFAULT_RATES, **(rates or {})}
        self.message_interval = message_interval
        self.fluid_density = fluid_density
        self.surface_pressure_hpa = surface_pressure_hpa
        self.reboot_s = reboot_s
        self.params = SimParams({"FS_PILOT_TIMEOUT": pilot_timeout_s, "FS_GCS_TIMEOUT": gcs_timeout_s,
                                 "FS_GCS_ENABLE": GCS_FAILSAFE_ACTIONS.index(gcs_failsafe)})
        """What the firmware keeps in its parameters (kept across a reboot, as on the vehicle's storage)."""
        self.clock = clock
        self.wall_clock = wall_clock
        # with a key, ArduSub (on SERIAL1 and up, where a router or companion sits) drops every unsigned or badly
        # signed packet, reads included, and says nothing about it
        self.link = MavLink(connection, MavlinkConfig(system_id=system_id, component_id=1,
                                                      signing_key_file=signing_key_file, accept_unsigned_reads=False),
                            clock=clock, name="sim-ardusub", heartbeat=False)
        self.link.signing.announce_refusals = False
        self.link.subscribe(self._on_setup_signing, ["SETUP_SIGNING"])
        self.link.subscribe(self._on_message, ["COMMAND_LONG", "REQUEST_DATA_STREAM", "HEARTBEAT", "MANUAL_CONTROL",
                                               "SET_MODE", "SET_GPS_GLOBAL_ORIGIN", "PARAM_REQUEST_LIST",
                                               "PARAM_REQUEST_READ", "PARAM_SET"])
        self.sent: dict[str, int] = dict.fromkeys(DEFAULT_RATES, 0)
        self.reboots = 0
        self.commands: list[tuple[int, float, float, int]] = []
        """(command, param1, param2, result) of every COMMAND_LONG handled, for tests and logs."""
        self.data_stream_requests: list[tuple[int, int, int]] = []
        self.statustexts: list[tuple[int, str]] = []
        """(severity, text) of every STATUSTEXT sent."""
        self.heartbeat_senders: set[tuple[int, int, int]] = set()
        """(system, component, MAV_TYPE) of every peer heartbeat seen."""
        self.manual_control_senders: set[tuple[int, int]] = set()
        """(system, component) of every MANUAL_CONTROL sender, whether the firmware would take its input or not."""
        self._lock = threading.Lock()
        self._armed: bool | None = None  # None: as the dive profile says
        self._mode: str | None = None
        self._gcs_origin: Origin | None = None
        self._pilot: tuple[float, float, float, float, float] | None = None
        """Flown, not scripted, since t0: (depth at t0, t0 in profile time, rate down m/s, north, east)."""
        self._start = clock()
        self.failsafe_checks = Failsafes(self.params, self, clock)
        """The pilot-input and GCS failsafes: told what the vehicle hears, checked on every tick."""
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
        self.failsafe_checks.start(self._start)
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
            self._armed = self._mode = self._gcs_origin = self._pilot = None
        self.failsafe_checks.reboot()
        log.info("sim-ardusub: rebooting (back in %.1f s)", self.reboot_s)

    @property
    def failsafes(self) -> list[tuple[float, str]]:
        """(seconds since start, "pilot_input" | "gcs") of every failsafe the vehicle went into."""
        return self.failsafe_checks.events

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
        """The vehicle now: the scripted dive, with depth flown by the pilot once MANUAL_CONTROL took over."""
        return self.state_at(self.clock() - self._start)

    def state_at(self, t: float) -> VehicleState:
        """The vehicle ``t`` seconds after start (the pilot's depth is exact only for times since their last input)."""
        s = self.profile.state(t)
        with self._lock:
            pilot, mode, armed = self._pilot, self._mode, self._armed
        if pilot is not None:
            d0, t0, rate, north, east = pilot
            depth = max(0.0, d0 + rate * (t - t0))
            s = replace(s, depth=depth, vd=rate if depth > 0 or rate > 0 else 0.0, vn=0.0, ve=0.0, north=north,
                        east=east, lat=None, lon=None, alt_m=None)  # the geodetic fields come from origin()
        if mode is not None:
            s = replace(s, mode=mode)
        if armed is not None:
            s = replace(s, armed=armed)
        return s

    def origin(self) -> Origin | None:
        """The EKF origin if the vehicle has one yet (``after_s`` after boot), or the one a ground station set."""
        with self._lock:
            if self._gcs_origin is not None:
                return self._gcs_origin
        o = self.profile.origin
        return o if o is not None and self.clock() - self._boot >= o.after_s else None

    def statustext(self, severity: int, text: str) -> None:
        """Say something to every ground station, as the firmware's ``gcs().send_text`` does."""
        self.statustexts.append((severity, text))
        log.info("sim-ardusub: %s", text)
        self.link.send(mav2.MAVLink_statustext_message(severity, text.encode()[:50]))

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
            self.failsafe_checks.check(now)
            with self._lock:
                due = [n for n, iv in self._intervals.items() if iv is not None and now >= self._due[n]]
                for n in due:
                    iv = self._intervals[n]
                    nxt = self._due[n] + iv
                    self._due[n] = nxt if nxt > now else now + iv
            for name in due:
                self._emit(name)

    def _emit(self, name: str) -> None:
        if name == "LOCAL_POSITION_NED" and self.origin() is None:
            return  # the EKF has no position estimate without an origin: ArduSub sends nothing
        msg = self.build(name)
        if self.link.send(msg):
            self.sent[name] += 1

    def build(self, name: str) -> mav2.MAVLink_message:
        """One message of the kind ``name`` describing the vehicle now."""
        now = self.clock()
        at = Moment(boot_ms=self.time_boot_ms(), wall_s=self.wall_clock(), since_start_s=now - self._start,
                    origin=self.origin(), surface_pressure_hpa=self.surface_pressure_hpa,
                    fluid_density=self.fluid_density, failsafe=self.failsafe_checks.active)
        return build_message(name, self.state(), at)

    # ------------------------------------------------------------------------------------------ commands
    def _for_us(self, target_system: int, target_component: int) -> bool:
        return target_system in (0, self.link.system_id) and target_component in (0, self.link.component_id)

    def _on_message(self, msg: mav2.MAVLink_message) -> None:
        """The one dispatch of everything the vehicle hears (runs on the link's receive thread: no waiting)."""
        if self.silent:
            return
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype == "HEARTBEAT":
            if src != (self.link.system_id, self.link.component_id):
                self.heartbeat_senders.add((*src, msg.type))
                if src[0] == self.params.gcs_sysid():
                    self.failsafe_checks.gcs_heard(self.clock())
            return
        if mtype == "MANUAL_CONTROL":
            self.manual_control_senders.add(src)
            if src[0] == self.params.gcs_sysid() and msg.target == self.link.system_id:  # the GCS's, aimed at us
                self._manual_control(msg)
                self.failsafe_checks.gcs_heard(self.clock())  # "considered to be a 'heartbeat' from the GCS"
            return
        if mtype == "SET_MODE":
            if msg.target_system in (0, self.link.system_id):
                self.set_mode(msg.custom_mode)
            return
        if mtype == "SET_GPS_GLOBAL_ORIGIN":
            if msg.target_system in (0, self.link.system_id):
                with self._lock:
                    self._gcs_origin = Origin(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0, 0.0)
            return
        if not self._for_us(msg.target_system, msg.target_component):
            return
        if mtype == "REQUEST_DATA_STREAM":
            self._data_stream(msg)
            return
        if mtype.startswith("PARAM_"):
            self.params.handle(msg, self.link.send, self.statustext)
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
        if cmd == mav2.MAV_CMD_COMPONENT_ARM_DISARM:
            if not math.isfinite(p1):
                return mav2.MAV_RESULT_DENIED
            self.set_armed(p1 == 1)
            return mav2.MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_DO_SET_MODE:
            if not math.isfinite(p2) or int(p2) not in mavutil.mode_mapping_sub:
                return mav2.MAV_RESULT_DENIED
            self.set_mode(int(p2))
            return mav2.MAV_RESULT_ACCEPTED
        return mav2.MAV_RESULT_UNSUPPORTED

    # ------------------------------------------------------------------------------------------ pilot
    def armed_at(self, now: float) -> bool:
        """Whether the vehicle is armed at ``now`` (its clock): by command, or as the script says."""
        return self.state_at(now - self._start).armed

    def set_armed(self, armed: bool) -> None:
        if not armed:
            self.fly(self.clock(), 0.0)  # thrusters off: the script no longer flies it (buoyancy not modelled)
        with self._lock:
            self._armed = armed
        self.failsafe_checks.armed_changed()
        log.info("sim-ardusub: %s", "armed" if armed else "disarmed")

    def set_mode(self, custom_mode: int) -> None:
        with self._lock:
            self._mode = mavutil.mode_mapping_sub.get(custom_mode, self._mode)

    def _manual_control(self, msg: mav2.MAVLink_message) -> None:
        """The pilot flies: z 0..1000, 500 neutral (holds depth in ALT_HOLD), below 500 descends."""
        now = self.clock()
        armed = self.armed_at(now)
        stick = max(-1.0, min(1.0, (500 - msg.z) / 500.0))  # > 0: down
        speed = self.params.pilot_speed_dn_mps() if stick > 0 else self.params.pilot_speed_up_mps()
        rate = stick * speed if armed else 0.0
        self.fly(now, rate)
        self.failsafe_checks.pilot_input(now, armed)

    def fly(self, now: float, rate_mps: float) -> None:
        """From now on the vehicle stays where it is and moves vertically at ``rate_mps`` (down positive)."""
        t = now - self._start
        s = self.state_at(t)
        with self._lock:
            self._pilot = (s.depth, t, rate_mps, s.north, s.east)

    def _data_stream(self, msg: mav2.MAVLink_message) -> None:
        self.data_stream_requests.append((msg.req_stream_id, msg.req_message_rate, msg.start_stop))
        if msg.req_stream_id == mav2.MAV_DATA_STREAM_ALL:
            names = [n for group in DATA_STREAMS.values() for n in group]
        else:
            names = list(DATA_STREAMS.get(msg.req_stream_id, ()))
        on = msg.start_stop and msg.req_message_rate > 0
        for name in names:
            self._set_interval(name, 1.0 / msg.req_message_rate if on else None)


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
            "data_stream_requests": len(sim.data_stream_requests), "rx_bad": sim.link.rx_bad,
            "failsafes": [kind for _t, kind in sim.failsafes],
            "peers": sorted(f"{system}/{component}" for system, component, _type in sim.heartbeat_senders),
            "manual_control_from": sorted(f"{system}/{component}" for system, component in sim.manual_control_senders)}
