"""A short history of telemetry samples and the vehicle's pose at any companion time.

Depth and position are interpolated linearly between the samples around the asked time, attitude by quaternion
slerp. Depth samples that carry the autopilot's own vertical speed (GLOBAL_POSITION_INT.vz, from the EKF) are
joined by cubic Hermite curves instead, and a frame newer than the newest depth sample gets that sample moved on
by its vertical speed: a frame is tagged a few tenths of a second after capture, while GLOBAL_POSITION_INT comes
at ~3.2 Hz, so holding the last sample would put a 0.5 m/s descent up to 0.16 m off. Nothing else is
extrapolated: after the newest sample (or before the oldest) the nearest sample is used as is, and only while it
is younger than ``stale_after_s``; a pose whose nearest depth/attitude sample is older than that is tagged
``stale`` and carries no values at all, never a made-up pose.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from vehicle.autopilot.pose import Pose, wrap_heading

Quaternion = tuple[float, float, float, float]


def normalise(q: Sequence[float]) -> Quaternion:
    n = math.sqrt(sum(c * c for c in q))
    if n == 0 or not math.isfinite(n):
        raise ValueError(f"not a rotation quaternion: {tuple(q)}")
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def slerp(q0: Sequence[float], q1: Sequence[float], f: float) -> Quaternion:
    """Spherical interpolation of w-x-y-z quaternions along the shorter arc (f=0: q0, f=1: q1)."""
    a, b = normalise(q0), normalise(q1)
    dot = sum(x * y for x, y in zip(a, b, strict=True))
    if dot < 0:  # q and -q are the same rotation: take the short way round
        b, dot = tuple(-c for c in b), -dot
    if dot > 0.9995:  # nearly equal: linear interpolation is exact enough and avoids dividing by ~0
        return normalise([x + (y - x) * f for x, y in zip(a, b, strict=True)])
    theta = math.acos(min(1.0, dot))
    s0 = math.sin((1 - f) * theta) / math.sin(theta)
    s1 = math.sin(f * theta) / math.sin(theta)
    return normalise([s0 * x + s1 * y for x, y in zip(a, b, strict=True)])


def quaternion_to_euler(q: Sequence[float]) -> tuple[float, float, float]:
    """w-x-y-z quaternion to aerospace roll, pitch, yaw (radians), the inverse of ArduPilot's convention."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> Quaternion:
    """Aerospace (Z-Y-X) Euler angles to a w-x-y-z quaternion."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


@dataclass
class _Channel:
    """Time-ordered samples of one quantity; ``values`` are tuples of floats, ``tags`` any label per sample."""

    times: list[float] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    tags: list[Any] = field(default_factory=list)

    def add(self, t: float, value: tuple[float, ...], tag: Any = None) -> None:
        if self.times and t < self.times[-1]:  # rare: out-of-order arrival; keep the list sorted
            i = bisect.bisect_right(self.times, t)
            self.times.insert(i, t)
            self.values.insert(i, value)
            self.tags.insert(i, tag)
            return
        self.times.append(t)
        self.values.append(value)
        self.tags.append(tag)

    def prune(self, before: float) -> None:
        i = bisect.bisect_left(self.times, before)
        if i > 0:
            del self.times[:i], self.values[:i], self.tags[:i]

    def nearest_age(self, t: float) -> float | None:
        if not self.times:
            return None
        i = bisect.bisect_left(self.times, t)
        ages = [abs(self.times[j] - t) for j in (i - 1, i) if 0 <= j < len(self.times)]
        return min(ages)

    def around(self, t: float, limit: float) -> tuple[int, int, float] | None:
        """Indices (i, j) and fraction to interpolate at t, or None when the nearest sample is too old."""
        age = self.nearest_age(t)
        if age is None or age > limit:
            return None
        i = bisect.bisect_right(self.times, t)
        if i == 0:
            return 0, 0, 0.0
        if i == len(self.times):
            return i - 1, i - 1, 0.0
        t0, t1 = self.times[i - 1], self.times[i]
        return i - 1, i, (t - t0) / (t1 - t0) if t1 > t0 else 0.0

    def linear(self, t: float, limit: float) -> tuple[tuple[float, ...], Any] | None:
        where = self.around(t, limit)
        if where is None:
            return None
        i, j, f = where
        a, b = self.values[i], self.values[j]
        tag = self.tags[i] if f < 0.5 else self.tags[j]
        return tuple(x + (y - x) * f for x, y in zip(a, b, strict=True)), tag


WATER_LIMIT_S = 2.0
"""SCALED_PRESSURE2 comes about once a second (water temperature changes slowly): a sample this near still counts."""


class PoseHistory:
    """Thread-safe store of timestamped samples (companion clock) and ``pose_at(t)``; see the module docstring."""

    def __init__(self, stale_after_s: float = 1.0, history_s: float = 30.0,
                 clock: Callable[[], float] | None = None) -> None:
        self.stale_after_s = stale_after_s
        self.history_s = history_s
        self._lock = threading.Lock()
        self._depth = _Channel()
        self._attitude = _Channel()
        self._heading = _Channel()
        self._local = _Channel()
        self._global = _Channel()
        self._water = _Channel()
        self._newest = -math.inf

    def add_depth(self, t: float, depth_m: float, source: str, rate_mps: float | None = None) -> None:
        """``rate_mps``: the vertical speed the autopilot reported with this depth (positive down), if any."""
        self._add(self._depth, t, (depth_m, math.nan if rate_mps is None else rate_mps), source)

    def add_attitude(self, t: float, q: Sequence[float]) -> None:
        self._add(self._attitude, t, normalise(q))

    def add_heading(self, t: float, heading_deg: float) -> None:
        self._add(self._heading, t, (wrap_heading(heading_deg),))

    def add_local_position(self, t: float, north: float, east: float, down: float) -> None:
        self._add(self._local, t, (north, east, down))

    def add_global_position(self, t: float, lat: float, lon: float, alt_m: float) -> None:
        self._add(self._global, t, (lat, lon, alt_m))

    def add_water(self, t: float, pressure_hpa: float, temp_c: float) -> None:
        """The external pressure sensor's absolute pressure and water temperature (SCALED_PRESSURE2: the Bar30)."""
        self._add(self._water, t, (pressure_hpa, temp_c))

    def clear(self) -> None:
        """Forget every sample (an autopilot reboot restarts its clock, so old times mean nothing any more)."""
        with self._lock:
            for ch in (self._depth, self._attitude, self._heading, self._local, self._global, self._water):
                ch.prune(math.inf)
            # the new boot's times start below the old newest one; left as it was, pruning (which only runs
            # when a sample is the newest yet) would stop until the new uptime passed the old one
            self._newest = -math.inf

    def _add(self, channel: _Channel, t: float, value: tuple[float, ...], tag: Any = None) -> None:
        with self._lock:
            channel.add(t, value, tag)
            if t > self._newest:
                self._newest = t
                if channel.times[0] < t - 2 * self.history_s:  # prune in batches, not per sample
                    for ch in (self._depth, self._attitude, self._heading, self._local, self._global, self._water):
                        ch.prune(t - self.history_s)

    def pose_at(self, t: float) -> Pose:
        """The pose at companion time ``t``; ``stale`` (with no values) when no depth or attitude is near."""
        limit = self.stale_after_s
        with self._lock:
            ages = [a for a in (self._depth.nearest_age(t), self._attitude.nearest_age(t)) if a is not None]
            age = min(ages) if ages else math.inf
            if age > limit:
                return Pose(time=t, age_s=age, stale=True)
            fields: dict[str, Any] = {}
            depth = self._depth_at(t, limit)
            if depth is not None:
                fields["depth_m"], fields["depth_source"] = depth
            where = self._attitude.around(t, limit)
            if where is not None:
                i, j, f = where
                q = slerp(self._attitude.values[i], self._attitude.values[j], f)
                roll, pitch, yaw = quaternion_to_euler(q)
                fields.update(q=q, roll=roll, pitch=pitch, yaw=yaw, heading_deg=wrap_heading(math.degrees(yaw)))
            else:
                heading = self._heading_at(t, limit)
                if heading is not None:
                    fields["heading_deg"] = heading
            local = self._local.linear(t, limit)
            if local is not None:
                fields["north_m"], fields["east_m"], fields["down_m"] = local[0]
            glob = self._global.linear(t, limit)
            if glob is not None:
                fields["lat"], fields["lon"], fields["alt_m"] = glob[0]
            water = self._water.linear(t, max(limit, WATER_LIMIT_S))
            if water is not None:
                fields["pressure_hpa"], fields["water_temp_c"] = water[0]
        return Pose(time=t, age_s=age, stale=False, **fields)

    def _depth_at(self, t: float, limit: float) -> tuple[float, str] | None:
        """Depth at ``t``: Hermite between samples with speeds, speed-aided past the newest, else linear/nearest."""
        ch = self._depth
        where = ch.around(t, limit)
        if where is None:
            return None
        i, j, f = where
        (d0, v0), (d1, v1) = ch.values[i], ch.values[j]
        tag = ch.tags[i] if f < 0.5 else ch.tags[j]
        if i == j:
            dt = t - ch.times[i]
            if dt > 0 and math.isfinite(v0):  # after the newest sample: move on at the reported vertical speed
                return d0 + v0 * dt, tag
            return d0, tag
        if not (math.isfinite(v0) and math.isfinite(v1)):
            return d0 + (d1 - d0) * f, tag
        h = ch.times[j] - ch.times[i]
        f2, f3 = f * f, f * f * f
        return ((2 * f3 - 3 * f2 + 1) * d0 + (f3 - 2 * f2 + f) * h * v0 + (-2 * f3 + 3 * f2) * d1
                + (f3 - f2) * h * v1), tag

    def _heading_at(self, t: float, limit: float) -> float | None:
        where = self._heading.around(t, limit)
        if where is None:
            return None
        i, j, f = where
        a, b = self._heading.values[i][0], self._heading.values[j][0]
        delta = (b - a + 180.0) % 360.0 - 180.0  # the short way round through north
        return wrap_heading(a + delta * f)
