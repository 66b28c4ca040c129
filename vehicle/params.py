"""The MAVLink parameter protocol on the companion component: live tuning from QGroundControl or MAVProxy.

A PARAM_SET that passes its range check takes effect at once (``on_change``), is saved (temp file, fsync,
rename: a power cut leaves the old or the new file, never half of one) and is echoed with PARAM_VALUE; one that
fails is answered with the unchanged value, so the ground station shows what really holds. Integer parameters
travel as their value cast to float (ArduPilot's convention, which QGroundControl applies to an ArduSub system).
"""

from __future__ import annotations

import json
import logging
import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.atomic_write import atomic_write
from companion.config import Config

log = logging.getLogger(__name__)

ID_MAX = 16
FILE_VERSION = 1


@dataclass
class ParamSpec:
    name: str
    value: float
    minimum: float
    maximum: float
    integer: bool = False
    doc: str = ""

    @property
    def mav_type(self) -> int:
        return mav.MAV_PARAM_TYPE_INT32 if self.integer else mav.MAV_PARAM_TYPE_REAL32


def default_params(cfg: Config) -> list[ParamSpec]:
    """The tunable set, starting from the configuration (names at most 16 characters)."""
    return [
        ParamSpec("MERL_TAU_SS", cfg.queries.tau_ss, 0.01, 0.99, doc="semantic pre-sampling threshold"),
        ParamSpec("MERL_TAU_SES", cfg.enhance.tau_ses, 0.01, 0.99, doc="threshold after enhancement"),
        ParamSpec("MERL_K", cfg.sampler.k, 1, 1000, integer=True, doc="summary size"),
        ParamSpec("MERL_THUMB_B", cfg.surface.thumbnail_bytes, 300, 65000, integer=True,
                  doc="thumbnail byte budget"),
        ParamSpec("MERL_LINK_BPS", cfg.surface.budget_bytes_per_s, 100, 1_000_000, integer=True,
                  doc="link budget, bytes/s"),
        ParamSpec("MERL_ENHANCE", 0 if cfg.enhance.mode == "none" else 1, 0, 1, integer=True,
                  doc="enhancer off (0) or on (1)"),
    ]


def _param_id(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.split(b"\0", 1)[0].decode("ascii", errors="replace")
    return raw.split("\0", 1)[0]


class ParamServer:
    """Holds the values, answers the parameter protocol, persists changes to ``path`` (None: memory only)."""

    def __init__(self, specs: list[ParamSpec], *, system_id: Callable[[], int], component_id: int,
                 path: str | os.PathLike[str] | None = None,
                 on_change: Callable[[str, float], None] | None = None) -> None:
        for spec in specs:
            if len(spec.name) > ID_MAX:
                raise ValueError(f"parameter id {spec.name!r} is longer than {ID_MAX} characters")
        self._specs = {s.name: s for s in specs}
        self._order = [s.name for s in specs]
        self._system_id = system_id
        self.component_id = component_id
        self.path = Path(path) if path is not None else None
        self._callbacks: list[Callable[[str, float], None]] = [on_change] if on_change else []
        self._lock = threading.Lock()
        self.restored: dict[str, float] = self._load()

    def on_change(self, callback: Callable[[str, float], None]) -> None:
        self._callbacks.append(callback)

    def value(self, name: str) -> float:
        return self._specs[name].value

    def values(self) -> dict[str, float]:
        return {n: self._specs[n].value for n in self._order}

    # ---- persistence ----------------------------------------------------------------------------------------

    def _load(self) -> dict[str, float]:
        """Saved values that differ from the configuration (known names, in range); a bad file is logged and ignored."""
        if self.path is None or not self.path.exists():
            return {}
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            if data.get("version") != FILE_VERSION:
                raise ValueError(f"version {data.get('version')!r}, expected {FILE_VERSION}")
            saved = data["params"]
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            log.warning("%s: ignoring saved parameters (%s)", self.path, err)
            return {}
        restored = {}
        for name, value in saved.items():
            spec = self._specs.get(name)
            if spec is None or not isinstance(value, (int, float)) or not self._valid(spec, float(value)):
                log.warning("%s: ignoring saved %s=%r", self.path, name, value)
                continue
            if float(value) != spec.value:  # only what differs from the configuration needs replaying
                spec.value = float(value)
                restored[name] = float(value)
        return restored

    def _save(self) -> None:
        if self.path is None:
            return
        body = {"version": FILE_VERSION, "params": self.values()}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(self.path, json.dumps(body, indent=1) + "\n")

    # ---- protocol -------------------------------------------------------------------------------------------

    def _valid(self, spec: ParamSpec, value: float) -> bool:
        if not math.isfinite(value) or not spec.minimum <= value <= spec.maximum:
            return False
        return not spec.integer or value == int(value)

    def param_value(self, name: str) -> mav.MAVLink_param_value_message:
        spec = self._specs[name]
        return mav.MAVLink_param_value_message(name.encode("ascii"), float(spec.value), spec.mav_type,
                                               len(self._order), self._order.index(name))

    def _for_us(self, msg: mav.MAVLink_message) -> bool:
        return msg.target_system in (0, self._system_id()) and msg.target_component in (0, self.component_id)

    def handle(self, msg: mav.MAVLink_message) -> list[mav.MAVLink_message]:
        """PARAM_VALUE replies to PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET; [] for anything else."""
        kind = msg.get_type()
        if kind not in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET") or not self._for_us(msg):
            return []
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
        """Apply, persist and announce a new value; False (nothing changed) when it is out of range or refused."""
        spec = self._specs[name]
        with self._lock:
            if not self._valid(spec, value):
                log.warning("parameter %s=%r refused (range %g..%g)", name, value, spec.minimum, spec.maximum)
                return False
            if value == spec.value:
                return True
            old = spec.value
            spec.value = value
            try:
                for callback in self._callbacks:
                    callback(name, value)
            except ValueError as err:
                spec.value = old
                log.warning("parameter %s=%r refused: %s", name, value, err)
                return False
            self._save()
        log.info("parameter %s set to %g", name, value)
        return True
