"""The MAVLink parameter protocol on the companion component: live tuning from QGroundControl or MAVProxy.

A PARAM_SET that passes its range check takes effect at once (``on_change``), is handed to ``persist`` (the app
saves it crash-safely; this side never touches files) and is echoed with PARAM_VALUE; one that fails is answered
with the unchanged value, so the ground station shows what really holds. Integer parameters
travel as their value cast to float (ArduPilot's convention, which QGroundControl applies to an ArduSub system).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.camera.requests import addressed_to

log = logging.getLogger(__name__)

ID_MAX = 16
REQUEST_TYPES = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")


@dataclass
class ParamSpec:
    name: str
    value: float
    minimum: float
    maximum: float
    integer: bool = False
    doc: str = ""

    @classmethod
    def around(cls, name: str, value: float, minimum: float, maximum: float, *, integer: bool = False,
               doc: str = "") -> ParamSpec:
        """The parameter with its usual range widened to take in ``value`` (a configuration may allow what the range
        does not, e.g. tau_ss 0.995 or a 2 MB/s link), so the value in force is never one a ground station could
        not set back."""
        value = float(value)
        return cls(name, value, min(minimum, value), max(maximum, value), integer=integer, doc=doc)

    @property
    def mav_type(self) -> int:
        return mav.MAV_PARAM_TYPE_INT32 if self.integer else mav.MAV_PARAM_TYPE_REAL32


def _param_id(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.split(b"\0", 1)[0].decode("ascii", errors="replace")
    return raw.split("\0", 1)[0]


class ParamServer:
    """Holds the values and answers the parameter protocol.

    ``saved`` are the values a previous run persisted (unknown names and out-of-range values are dropped with a
    warning); ``persist(values)`` is called with every parameter after each accepted change (None: memory only).
    """

    def __init__(self, specs: list[ParamSpec], *, system_id: Callable[[], int], component_id: int,
                 saved: Mapping[str, float] | None = None,
                 persist: Callable[[dict[str, float]], None] | None = None,
                 on_change: Callable[[str, float], None] | None = None) -> None:
        for spec in specs:
            if len(spec.name) > ID_MAX:
                raise ValueError(f"parameter id {spec.name!r} is longer than {ID_MAX} characters")
        self._specs = {s.name: s for s in specs}
        self._order = [s.name for s in specs]
        self._system_id = system_id
        self.component_id = component_id
        self._persist = persist
        self._callbacks: list[Callable[[str, float], None]] = [on_change] if on_change else []
        self._lock = threading.Lock()
        self.restored: dict[str, float] = self._restore(saved or {})

    def on_change(self, callback: Callable[[str, float], None]) -> None:
        self._callbacks.append(callback)

    def value(self, name: str) -> float:
        return self._specs[name].value

    def values(self) -> dict[str, float]:
        return {n: self._specs[n].value for n in self._order}

    # ---- persistence ----------------------------------------------------------------------------------------

    def _restore(self, saved: Mapping[str, float]) -> dict[str, float]:
        """Saved values that differ from the configuration (known names, in range); the rest is logged and dropped."""
        restored = {}
        for name, value in saved.items():
            spec = self._specs.get(name)
            if spec is None or not isinstance(value, (int, float)) or not self._valid(spec, float(value)):
                log.warning("ignoring saved parameter %s=%r", name, value)
                continue
            if float(value) != spec.value:  # only what differs from the configuration needs replaying
                spec.value = float(value)
                restored[name] = float(value)
        return restored

    def _save(self) -> None:
        if self._persist is not None:
            self._persist(self.values())

    # ---- protocol -------------------------------------------------------------------------------------------

    def _valid(self, spec: ParamSpec, value: float) -> bool:
        if not math.isfinite(value) or not spec.minimum <= value <= spec.maximum:
            return False
        return not spec.integer or value == int(value)

    def param_value(self, name: str) -> mav.MAVLink_param_value_message:
        spec = self._specs[name]
        return mav.MAVLink_param_value_message(name.encode("ascii"), float(spec.value), spec.mav_type,
                                               len(self._order), self._order.index(name))

    def handle(self, msg: mav.MAVLink_message) -> list[mav.MAVLink_message]:
        """PARAM_VALUE replies to PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET; [] for anything else or not
        for us (standalone use: the downlink's ``RequestRouter`` checks the target and calls ``answer``)."""
        if msg.get_type() not in REQUEST_TYPES or not addressed_to(msg, (self._system_id(), self.component_id)):
            return []
        return self.answer(msg)

    def answer(self, msg: mav.MAVLink_message) -> list[mav.MAVLink_message]:
        """The PARAM_VALUE replies to a parameter request addressed to us."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.param_value(n) for n in self._order]
        if kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:
                if msg.param_index >= len(self._order):
                    return []
                return [self.param_value(self._order[msg.param_index])]
            name = _param_id(msg.param_id)
            return [self.param_value(name)] if name in self._specs else []
        name = _param_id(msg.param_id)
        if name not in self._specs:
            return []
        self.set(name, float(msg.param_value))
        return [self.param_value(name)]

    def set(self, name: str, value: float) -> bool:
        """Apply, persist and announce a new value; False (nothing changed) when it is out of range or refused.

        The callbacks run before the lock is taken: they apply the change (the companion's may wait for its
        summary keeper's turn), and no other reader of the values waits behind them; the lock covers only the
        new value and its save.
        """
        spec = self._specs[name]
        if not self._valid(spec, value):
            log.warning("parameter %s=%r refused (range %g..%g)", name, value, spec.minimum, spec.maximum)
            return False
        if value == spec.value:
            return True
        try:
            for callback in self._callbacks:
                callback(name, value)
        except ValueError as err:
            log.warning("parameter %s=%r refused: %s", name, value, err)
            return False
        with self._lock:
            spec.value = value
            self._save()
        log.info("parameter %s set to %g", name, value)
        return True
