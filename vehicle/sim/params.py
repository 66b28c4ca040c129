"""The simulated ArduSub's parameters, served as ArduPilot's ``GCS_Param.cpp`` serves them.

Only the parameters the simulator acts on are here, with ArduSub 4.7's names, MAVLink types and defaults
(``ArduSub/Parameters.cpp``/``Parameters.h``; PILOT_SPEED_UP's 100 cm/s comes from ArduSub's own defaults table,
which overrides the generic 500): a ground station (or a test) that reads or changes them sees what the firmware
would show, and the simulator's failsafes and pilot response follow the values set.

The protocol, as the firmware answers it:

- PARAM_REQUEST_LIST: the banner (STATUSTEXT), then every parameter as PARAM_VALUE with its index and the count;
- PARAM_REQUEST_READ by index (``param_index`` >= 0) or by name (-1): one PARAM_VALUE carrying the request's own
  ``param_index`` (so -1, 65535 on the wire, for a read by name); an unknown name or index gets no answer at all;
- PARAM_SET: an unknown name, NaN or infinity is ignored without a word; otherwise the value is stored (integer types
  add 0.01 towards the sign, truncate and clamp to the type's range, as ``AP_Param::set_float``) and the new value is
  sent to everyone as PARAM_VALUE with index -1.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav2

INT8 = mav2.MAV_PARAM_TYPE_INT8
INT16 = mav2.MAV_PARAM_TYPE_INT16
REAL32 = mav2.MAV_PARAM_TYPE_REAL32
_INT_RANGE = {INT8: (-128, 127), INT16: (-32768, 32767)}

BANNER = ("ArduSub V4.7.0-dev (simulated)", "Frame: VECTORED")
"""What ``send_banner`` says before a parameter list (firmware version, then the frame)."""


@dataclass(frozen=True)
class Param:
    name: str
    mav_type: int
    default: float
    meaning: str


ARDUSUB_PARAMS: tuple[Param, ...] = (
    Param("FS_GCS_ENABLE", INT8, 2, "GCS failsafe action: 0 off, 1 warn, 2 disarm, 3 depth hold, 4 surface"),
    Param("FS_GCS_TIMEOUT", REAL32, 5.0, "s without a heartbeat (or MANUAL_CONTROL) from MAV_GCS_SYSID"),
    Param("FS_PILOT_INPUT", INT8, 2, "pilot-input failsafe action: 0 off, 1 warn, 2 disarm"),
    Param("FS_PILOT_TIMEOUT", REAL32, 3.0, "s without MANUAL_CONTROL before the pilot-input failsafe"),
    Param("MAV_GCS_SYSID", INT16, 255, "the ground station: its heartbeats and MANUAL_CONTROL count, no one else's"),
    Param("PILOT_SPEED_DN", INT16, 0, "cm/s descent at full stick; 0: PILOT_SPEED_UP"),
    Param("PILOT_SPEED_UP", INT16, 100, "cm/s ascent at full stick"),
)
BY_NAME = {p.name: p for p in ARDUSUB_PARAMS}
GCS_FAILSAFE_ACTIONS = ("off", "warn", "disarm", "depth_hold", "surface")
"""FS_GCS_ENABLE 0-4, by name (the command line's words)."""


def coerce(param: Param, value: float) -> float | None:
    """The value ``param`` keeps when set to ``value`` (None: refused, as NaN and infinity are)."""
    if not math.isfinite(value):
        return None
    if param.mav_type == REAL32:
        return float(value)
    low, high = _INT_RANGE[param.mav_type]
    return float(max(low, min(high, math.trunc(value + math.copysign(0.01, value)))))


class SimParams:
    """The parameter table of one simulated autopilot; ``handle`` answers the protocol, ``value`` reads for the sim."""

    def __init__(self, overrides: dict[str, float] | None = None) -> None:
        self._lock = threading.Lock()
        self._values = {p.name: float(p.default) for p in ARDUSUB_PARAMS}
        for name, value in (overrides or {}).items():
            if self.set(name, value) is None:
                raise ValueError(f"parameter {name} cannot be {value!r}")
        self.sets: list[tuple[str, float]] = []
        """(name, value kept) of every PARAM_SET taken from the wire, for tests and logs."""

    def value(self, name: str) -> float:
        with self._lock:
            return self._values[name]

    def gcs_sysid(self) -> int:
        """MAV_GCS_SYSID: the one system whose heartbeats and MANUAL_CONTROL count."""
        return int(self.value("MAV_GCS_SYSID"))

    def pilot_speed_up_mps(self) -> float:
        """m/s at full up stick (PILOT_SPEED_UP, cm/s)."""
        return abs(self.value("PILOT_SPEED_UP")) / 100.0

    def pilot_speed_dn_mps(self) -> float:
        """m/s at full down stick: PILOT_SPEED_DN, or PILOT_SPEED_UP when that is 0 (``get_pilot_speed_dn``)."""
        dn = self.value("PILOT_SPEED_DN")
        return abs(dn) / 100.0 if dn != 0 else self.pilot_speed_up_mps()

    def set(self, name: str, value: float) -> float | None:
        """Store ``value`` (coerced to the parameter's type); the value kept, or None if refused or unknown."""
        param = BY_NAME.get(name)
        kept = coerce(param, value) if param is not None else None
        if kept is not None:
            with self._lock:
                self._values[name] = kept
        return kept

    def handle(self, msg: mav2.MAVLink_message, send: Callable[[mav2.MAVLink_message], int],
               say: Callable[[int, str], None]) -> None:
        """Answer one PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET already addressed to this autopilot."""
        mtype = msg.get_type()
        if mtype == "PARAM_REQUEST_LIST":
            for line in BANNER:
                say(mav2.MAV_SEVERITY_INFO, line)
            for index, param in enumerate(ARDUSUB_PARAMS):
                send(self._value_message(param, index))
        elif mtype == "PARAM_REQUEST_READ":
            param = self._find(msg)
            if param is not None:
                send(self._value_message(param, msg.param_index))
        elif mtype == "PARAM_SET":
            name = _name(msg.param_id)
            kept = self.set(name, msg.param_value)
            if kept is not None:
                self.sets.append((name, kept))
                send(self._value_message(BY_NAME[name], -1))

    def _find(self, msg: mav2.MAVLink_message) -> Param | None:
        if msg.param_index >= 0:
            return ARDUSUB_PARAMS[msg.param_index] if msg.param_index < len(ARDUSUB_PARAMS) else None
        return BY_NAME.get(_name(msg.param_id))

    def _value_message(self, param: Param, index: int) -> mav2.MAVLink_message:
        return mav2.MAVLink_param_value_message(param.name.encode(), self.value(param.name), param.mav_type,
                                                len(ARDUSUB_PARAMS), index & 0xFFFF)  # -1 is 65535 in a uint16


def _name(param_id: str | bytes) -> str:
    """A parameter name from the wire (16 characters, NUL-padded, as pymavlink hands it over)."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", errors="replace")
    return param_id.split("\x00", 1)[0]
