"""A scripted dive for the simulated ArduSub: legs (descend, hold, lawn-mower survey, go to, ascend) in YAML.

The legs compile into a piecewise-linear track of keyframes, so the vehicle state at any time is exact and cheap
to compute, and tests can predict what the simulator will report. Example profile::

    origin: {lat: 1.2644, lon: 103.8222, alt_m: 0.0, after_s: 16}   # EKF origin (set 16 s after boot, as in
                                                                     # ArduSub SITL); leave out: no position source
    loop: true                                           # start over at the end
    legs:
      - descend: {to_m: 8, rate_mps: 0.5}
      - lawnmower: {lanes: 4, length_m: 20, spacing_m: 4, speed_mps: 0.5}
      - ascend: {to_m: 0, rate_mps: 0.5}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from vehicle.errors import UsageError

_EARTH_RADIUS_M = 6378137.0
ORIGIN_AFTER_S = 16.0
"""ArduSub SITL's EKF sets its origin about this long after boot (with a position source)."""
_LEG_KEYS = {
    "descend": {"to_m", "rate_mps", "mode"},
    "ascend": {"to_m", "rate_mps", "mode"},
    "hold": {"s", "mode"},
    "goto": {"north_m", "east_m", "depth_m", "speed_mps", "mode"},
    "lawnmower": {"lanes", "length_m", "spacing_m", "speed_mps", "mode"},
}


@dataclass(frozen=True)
class Keyframe:
    t: float
    north: float
    east: float
    depth: float
    yaw: float
    mode: str


@dataclass(frozen=True)
class VehicleState:
    """The simulated vehicle at one moment: position (NED, metres), velocity (m/s), attitude (radians)."""

    t: float
    north: float
    east: float
    depth: float
    vn: float
    ve: float
    vd: float
    roll: float
    pitch: float
    yaw: float
    mode: str
    armed: bool
    lat: float | None
    lon: float | None
    alt_m: float | None


@dataclass(frozen=True)
class Origin:
    """Where the EKF puts north/east 0; ``after_s``: seconds after boot until it has it (ArduSub SITL: ~16 s)."""

    lat: float
    lon: float
    alt_m: float = 0.0
    after_s: float = ORIGIN_AFTER_S


def geodetic(origin: Origin, north: float, east: float, depth: float) -> tuple[float, float, float]:
    """(lat, lon, alt_m) of a point ``north``/``east``/``depth`` metres from ``origin`` (flat earth, fine for a dive)."""
    lat = origin.lat + math.degrees(north / _EARTH_RADIUS_M)
    lon = origin.lon + math.degrees(east / (_EARTH_RADIUS_M * math.cos(math.radians(origin.lat))))
    return lat, lon, origin.alt_m - depth


class DiveProfile:
    """A compiled dive; ``state(t)`` gives the vehicle at ``t`` seconds after the simulator started."""

    def __init__(self, keyframes: list[Keyframe], *, origin: Origin | None, loop: bool, armed: bool = True,
                 sway_deg: float = 3.0) -> None:
        if len(keyframes) < 2:
            raise UsageError("dive profile: needs at least one leg that takes time")
        self.keyframes = keyframes
        self.origin = origin
        self.loop = loop
        self.armed = armed
        self.sway = math.radians(sway_deg)
        self.duration = keyframes[-1].t

    def _segment(self, t: float) -> tuple[Keyframe, Keyframe, float]:
        if self.loop:
            t = t % self.duration
        t = min(max(t, 0.0), self.duration)
        frames = self.keyframes
        lo, hi = 0, len(frames) - 1
        while hi - lo > 1:  # binary search for the keyframes around t
            mid = (lo + hi) // 2
            if frames[mid].t <= t:
                lo = mid
            else:
                hi = mid
        a, b = frames[lo], frames[hi]
        span = b.t - a.t
        return a, b, (t - a.t) / span if span > 0 else 0.0

    def state(self, t: float) -> VehicleState:
        a, b, f = self._segment(t)
        span = max(b.t - a.t, 1e-9)
        north = a.north + (b.north - a.north) * f
        east = a.east + (b.east - a.east) * f
        depth = a.depth + (b.depth - a.depth) * f
        vn, ve, vd = (b.north - a.north) / span, (b.east - a.east) / span, (b.depth - a.depth) / span
        yaw = b.yaw if (b.north, b.east) != (a.north, a.east) else a.yaw
        # a gentle sway so that attitude interpolation has something to do
        roll = self.sway * math.sin(2 * math.pi * t / 7.0)
        pitch = 0.5 * self.sway * math.sin(2 * math.pi * t / 11.0)
        lat = lon = alt = None
        if self.origin is not None:
            lat, lon, alt = geodetic(self.origin, north, east, depth)
        return VehicleState(t, north, east, depth, vn, ve, vd, roll, pitch, yaw, b.mode, self.armed, lat, lon, alt)


def _number(leg: str, data: dict[str, Any], key: str, default: float | None, *, positive: bool = True) -> float:
    value = data.get(key, default)
    if value is None:
        raise UsageError(f"dive profile: leg {leg!r} needs {key}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"dive profile: leg {leg!r} {key} must be a number, got {value!r}") from None
    if positive and value <= 0:
        raise UsageError(f"dive profile: leg {leg!r} {key} must be > 0, got {value}")
    if value < 0 and key in ("to_m", "depth_m"):
        raise UsageError(f"dive profile: leg {leg!r} {key} must be >= 0 (depth, positive down), got {value}")
    return value


def compile_profile(data: dict[str, Any], *, origin_name: str = "dive profile") -> DiveProfile:
    """Turn the YAML mapping into keyframes; errors name the leg and key."""
    if not isinstance(data, dict):
        raise UsageError(f"{origin_name}: top level must be a mapping with 'legs'")
    unknown = set(data) - {"origin", "loop", "legs", "armed", "sway_deg"}
    if unknown:
        raise UsageError(f"{origin_name}: unknown key {sorted(unknown)[0]!r}")
    legs = data.get("legs")
    if not isinstance(legs, list) or not legs:
        raise UsageError(f"{origin_name}: 'legs' must be a non-empty list")
    origin = None
    if data.get("origin") is not None:
        o = data["origin"]
        try:
            origin = Origin(float(o["lat"]), float(o["lon"]), float(o.get("alt_m", 0.0)),
                            float(o.get("after_s", ORIGIN_AFTER_S)))
        except (TypeError, KeyError, ValueError, AttributeError):
            raise UsageError(f"{origin_name}: origin needs numeric lat and lon (and alt_m, after_s)") from None
        if origin.after_s < 0:
            raise UsageError(f"{origin_name}: origin.after_s must be >= 0, got {origin.after_s}")
    frames = [Keyframe(0.0, 0.0, 0.0, 0.0, 0.0, "MANUAL")]

    def add(dt: float, north: float, east: float, depth: float, mode: str) -> None:
        last = frames[-1]
        yaw = math.atan2(east - last.east, north - last.north) if (north, east) != (last.north, last.east) \
            else last.yaw
        frames.append(Keyframe(last.t + dt, north, east, depth, yaw, mode))

    for i, leg in enumerate(legs):
        if not isinstance(leg, dict) or len(leg) != 1:
            raise UsageError(f"{origin_name}: leg {i + 1} must be one of {sorted(_LEG_KEYS)} with its settings")
        kind, args = next(iter(leg.items()))
        args = args or {}
        if kind not in _LEG_KEYS:
            raise UsageError(f"{origin_name}: leg {i + 1}: unknown kind {kind!r} (one of {sorted(_LEG_KEYS)})")
        if not isinstance(args, dict) or set(args) - _LEG_KEYS[kind]:
            bad = sorted(set(args) - _LEG_KEYS[kind]) if isinstance(args, dict) else [args]
            raise UsageError(f"{origin_name}: leg {i + 1} ({kind}): unknown setting {bad[0]!r}")
        last = frames[-1]
        name = f"{i + 1} ({kind})"
        if kind in ("descend", "ascend"):
            to = _number(name, args, "to_m", None if kind == "descend" else 0.0, positive=False)
            rate = _number(name, args, "rate_mps", 0.5)
            dt = abs(to - last.depth) / rate
            if dt > 0:
                add(dt, last.north, last.east, to, args.get("mode", "MANUAL"))
        elif kind == "hold":
            add(_number(name, args, "s", None), last.north, last.east, last.depth, args.get("mode", "ALT_HOLD"))
        elif kind == "goto":
            n = _number(name, args, "north_m", last.north, positive=False)
            e = _number(name, args, "east_m", last.east, positive=False)
            d = _number(name, args, "depth_m", last.depth, positive=False)
            speed = _number(name, args, "speed_mps", 0.5)
            dist = math.dist((n, e, d), (last.north, last.east, last.depth))
            if dist > 0:
                add(dist / speed, n, e, d, args.get("mode", "ALT_HOLD"))
        else:
            lanes = int(_number(name, args, "lanes", 4))
            length = _number(name, args, "length_m", 20.0)
            spacing = _number(name, args, "spacing_m", 4.0)
            speed = _number(name, args, "speed_mps", 0.5)
            mode = args.get("mode", "ALT_HOLD")
            north0, east = last.north, last.east
            for lane in range(lanes):
                north = north0 + (length if lane % 2 == 0 else 0.0)
                add(length / speed, north, east, last.depth, mode)
                if lane < lanes - 1:
                    east += spacing
                    add(spacing / speed, north, east, last.depth, mode)
    return DiveProfile(frames, origin=origin, loop=bool(data.get("loop", True)), armed=bool(data.get("armed", True)),
                       sway_deg=float(data.get("sway_deg", 3.0)))


DEFAULT_PROFILE: dict[str, Any] = {
    "origin": {"lat": 1.2644, "lon": 103.8222, "alt_m": 0.0},
    "loop": True,
    "legs": [
        {"hold": {"s": 2, "mode": "MANUAL"}},
        {"descend": {"to_m": 8.0, "rate_mps": 0.5}},
        {"lawnmower": {"lanes": 4, "length_m": 20.0, "spacing_m": 4.0, "speed_mps": 0.5}},
        {"ascend": {"to_m": 0.0, "rate_mps": 0.5, "mode": "SURFACE"}},
    ],
}


def load_profile(path: str | Path | None) -> DiveProfile:
    """The YAML profile at ``path``, or the built-in dive (descend to 8 m, 4-lane survey, ascend) when None."""
    if path is None:
        return compile_profile(DEFAULT_PROFILE, origin_name="built-in dive profile")
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{p}: no such dive profile") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise UsageError(f"{p}: cannot read dive profile ({type(err).__name__})") from None
    return compile_profile(data, origin_name=str(p))
