"""The vehicle's pose at a moment, as attached to a summary frame."""

from __future__ import annotations

from dataclasses import asdict, dataclass


def wrap_heading(degrees: float) -> float:
    """``degrees`` as a compass heading in [0, 360). Python's ``%`` alone gives 360.0 for a tiny negative angle
    (``-1e-17 % 360.0``: a yaw a hair west of north), a heading no compass shows and an export must not carry."""
    heading = degrees % 360.0
    return 0.0 if heading >= 360.0 else heading


@dataclass(frozen=True)
class Pose:
    """Where the vehicle was and how it was oriented at ``time`` (companion wall clock, seconds since epoch).

    Fields the vehicle did not report are None. ``stale`` is True when the nearest telemetry sample is older than
    the configured limit: then only ``time``, ``age_s`` and ``stale`` are meaningful, nothing is made up.
    """

    time: float
    age_s: float
    stale: bool
    depth_m: float | None = None
    """Positive down, metres below the surface."""
    depth_source: str | None = None
    """global_position_int | scaled_pressure2 | vfr_hud."""
    roll: float | None = None
    """Radians."""
    pitch: float | None = None
    yaw: float | None = None
    q: tuple[float, float, float, float] | None = None
    """Attitude quaternion, w-x-y-z (MAVLink order)."""
    heading_deg: float | None = None
    lat: float | None = None
    """Degrees, only when the EKF has an origin."""
    lon: float | None = None
    alt_m: float | None = None
    """AMSL metres, only when known."""
    north_m: float | None = None
    """LOCAL_POSITION_NED, only with a position source (DVL, USBL)."""
    east_m: float | None = None
    down_m: float | None = None
    water_temp_c: float | None = None
    """Water temperature from the external pressure sensor (SCALED_PRESSURE2.temperature: the Bar30), degC."""
    pressure_hpa: float | None = None
    """Absolute water pressure there (SCALED_PRESSURE2.press_abs), hPa."""
    time_boot_ms: int | None = None
    """The autopilot's own clock at ``time`` (milliseconds since its boot), beside the companion's ``time``."""
    autopilot_unix_usec: int | None = None
    """The autopilot's UTC at ``time`` (SYSTEM_TIME's time_unix_usec carried forward on its boot clock), when it has
    one: a frame's time that survives a companion clock that is wrong or jumps."""

    def to_dict(self) -> dict:
        return asdict(self)
