"""The simulated ArduSub's telemetry messages: what each would say about the vehicle's state, field by field.

Kept apart from the simulator's timing and command handling so that the wire contents (units, scaling, what is 0
before the EKF has an origin) can be read in one place against ArduSub's own ``GCS_MAVLink`` senders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.autopilot.pose_history import euler_to_quaternion
from vehicle.autopilot.telemetry import GRAVITY
from vehicle.sim.dive_profile import Origin, VehicleState, geodetic

MODE_NUMBERS = {name: number for number, name in mavutil.mode_mapping_sub.items()}
GUIDED_MODES = frozenset({"AUTO", "GUIDED", "CIRCLE", "POSHOLD"})
"""Modes whose heartbeat carries MAV_MODE_FLAG_GUIDED_ENABLED (GCS_MAVLINK_Sub::base_mode)."""


@dataclass(frozen=True)
class Moment:
    """What a message is built from besides the vehicle's state: its clocks, origin and sensors' environment."""

    boot_ms: int
    wall_s: float
    since_start_s: float
    origin: Origin | None
    surface_pressure_hpa: float
    fluid_density: float
    failsafe: bool = False
    """A failsafe has triggered (and not cleared): the heartbeat says MAV_STATE_CRITICAL."""


def build_message(name: str, s: VehicleState, at: Moment) -> mav2.MAVLink_message:
    """One message of the kind ``name`` describing the vehicle in state ``s``."""
    boot_ms, origin = at.boot_ms, at.origin
    heading = math.degrees(s.yaw) % 360.0
    if name == "HEARTBEAT":  # as GCS_MAVLINK_Sub::base_mode and vehicle_system_status
        base = (mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav2.MAV_MODE_FLAG_STABILIZE_ENABLED
                | mav2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
        if s.mode in GUIDED_MODES:
            base |= mav2.MAV_MODE_FLAG_GUIDED_ENABLED
        if s.armed:
            base |= mav2.MAV_MODE_FLAG_SAFETY_ARMED
        status = (mav2.MAV_STATE_CRITICAL if at.failsafe else mav2.MAV_STATE_ACTIVE if s.armed
                  else mav2.MAV_STATE_STANDBY)
        return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                                              MODE_NUMBERS.get(s.mode, 19), status, 3)
    if name == "SYSTEM_TIME":
        return mav2.MAVLink_system_time_message(int(at.wall_s * 1e6), boot_ms)
    if name == "ATTITUDE":
        return mav2.MAVLink_attitude_message(boot_ms, s.roll, s.pitch, _wrap_pi(s.yaw), 0.0, 0.0, 0.0)
    if name == "ATTITUDE_QUATERNION":
        w, x, y, z = euler_to_quaternion(s.roll, s.pitch, s.yaw)
        return mav2.MAVLink_attitude_quaternion_message(boot_ms, w, x, y, z, 0.0, 0.0, 0.0, [0.0] * 4)
    if name == "GLOBAL_POSITION_INT":
        lat = lon = alt = 0  # 0 until the EKF has an origin; relative_alt (from the depth sensor) always valid
        if origin is not None:
            glat, glon, galt = geodetic(origin, s.north, s.east, s.depth)
            lat, lon, alt = int(round(glat * 1e7)), int(round(glon * 1e7)), int(round(galt * 1000))
        return mav2.MAVLink_global_position_int_message(
            boot_ms, lat, lon, alt, int(round(-s.depth * 1000)), _cms(s.vn), _cms(s.ve), _cms(s.vd),
            int(round(heading * 100)) % 36000)
    if name == "LOCAL_POSITION_NED":
        return mav2.MAVLink_local_position_ned_message(boot_ms, s.north, s.east, s.depth, s.vn, s.ve, s.vd)
    if name == "VFR_HUD":
        alt = origin.alt_m - s.depth if origin is not None else 0.0  # 0 without an EKF origin, as on ArduSub
        return mav2.MAVLink_vfr_hud_message(0.0, math.hypot(s.vn, s.ve), int(heading), 0, alt, -s.vd)
    if name == "SCALED_PRESSURE":  # the flight controller's own barometer, inside the dry hull
        return mav2.MAVLink_scaled_pressure_message(boot_ms, at.surface_pressure_hpa, 0.0, 2500, 0)
    if name == "SCALED_PRESSURE2":
        press = at.surface_pressure_hpa + at.fluid_density * GRAVITY * s.depth / 100.0
        return mav2.MAVLink_scaled_pressure2_message(boot_ms, press, 0.0, 1500, 0)
    remaining = max(0, 100 - int(at.since_start_s / 60))
    volts = 12.8 + 3.2 * remaining / 100
    if name == "SYS_STATUS":
        return mav2.MAVLink_sys_status_message(0, 0, 0, 200, int(volts * 1000), 850, remaining, 0, 0, 0, 0, 0, 0)
    if name == "BATTERY_STATUS":
        cells = [int(volts * 1000)] + [65535] * 9
        return mav2.MAVLink_battery_status_message(0, 0, 0, 2500, cells, 850, -1, -1, remaining)
    raise ValueError(f"sim vehicle cannot send {name}")


def _cms(v: float) -> int:
    return int(round(v * 100))


def _wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi
