"""A dive log written with pymavlink for the archive tests: known depth and heading at every moment."""

from __future__ import annotations

import math
import struct
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav2


def depth_at(t: float, t0: float) -> float:
    """The written profile: 2 m at the start, descending 0.25 m/s (metres, positive down)."""
    return 2.0 + 0.25 * (t - t0)


def yaw_at(t: float, t0: float) -> float:
    return math.radians(10.0 + 2.0 * (t - t0))


def write_dive_log(path: Path, t0: float, duration_s: float, boot_s: float = 120.0) -> Path:
    """A tlog of an ArduSub that boots ``boot_s`` before ``t0``: heartbeat 1 Hz, ATTITUDE 10 Hz,
    GLOBAL_POSITION_INT 4 Hz, each record stamped with its wall time as QGroundControl writes it."""
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    records: list[tuple[float, bytes]] = []
    boot_wall = t0 - boot_s

    def boot_ms(t: float) -> int:
        return int(round((t - boot_wall) * 1000))

    steps = int(duration_s * 20)
    for i in range(steps + 1):
        t = t0 + i / 20.0
        if i % 20 == 0:
            msg = mav.heartbeat_encode(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 19, 4)
            records.append((t, msg.pack(mav)))
        if i % 2 == 0:
            msg = mav.attitude_encode(boot_ms(t), 0.01, -0.02, yaw_at(t, t0), 0, 0, 0)
            records.append((t + 0.004, msg.pack(mav)))
        if i % 5 == 0:
            rel_alt = int(round(-depth_at(t, t0) * 1000))
            msg = mav.global_position_int_encode(boot_ms(t), 0, 0, rel_alt, rel_alt, 0, 0, 0, 65535)
            records.append((t + 0.008, msg.pack(mav)))
    with path.open("wb") as f:
        for t, packet in records:
            f.write(struct.pack(">Q", int(t * 1e6)) + packet)
    return path
