"""Watch a vehicle's telemetry from the command line: the companion's own view of depth, attitude and mode.

Used by ``merlion telemetry`` to check a vehicle connection (or the simulator, or a log replay) before a dive,
with exactly the link, rate requests and time alignment the live companion uses.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from vehicle.autopilot.telemetry import TelemetrySnapshot, VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.settings import MavlinkConfig, TelemetryConfig


def describe(s: TelemetrySnapshot) -> str:
    """One human line for a snapshot."""
    if s.time is None:
        return "no telemetry yet"
    parts = [f"autopilot {'alive' if s.autopilot_alive else 'LOST'}"]
    if s.depth_m is not None:
        parts.append(f"depth {s.depth_m:.2f} m ({s.depth_source})")
    if s.roll is not None:
        parts.append(f"roll {math.degrees(s.roll):+.1f} pitch {math.degrees(s.pitch):+.1f} "
                     f"heading {round(s.heading_deg) % 360} deg")
    if s.north_m is not None:
        parts.append(f"NED {s.north_m:.1f}/{s.east_m:.1f}/{s.down_m:.1f} m")
    elif s.position_source is False:
        parts.append("no position source")
    if s.mode is not None:
        parts.append(f"{'armed' if s.armed else 'disarmed'} {s.mode}")
    if s.battery_v is not None:
        parts.append(f"battery {s.battery_v:.1f} V")
    if s.spoofed_ignored:
        parts.append(f"{s.spoofed_ignored} unsigned messages claiming to be the autopilot ignored")
    return ", ".join(parts)


def watch_telemetry(
    mavlink: MavlinkConfig,
    telemetry_cfg: TelemetryConfig,
    *,
    duration: float | None,
    report: Callable[[str], None] | None = None,
    every_s: float = 1.0,
    stop: threading.Event | None = None,
    request_rates: bool = True,
) -> dict[str, object]:
    """Connect as the companion would, print a line every ``every_s``, and return the final state and counters."""
    stop = stop or threading.Event()
    link = MavLink(mavlink.connection, mavlink, name="telemetry")
    telemetry = VehicleTelemetry(link, telemetry_cfg, request_rates=request_rates)
    telemetry.start()
    link.start()
    start = time.monotonic()
    max_depth = None
    try:
        while not stop.is_set():
            if duration is not None and time.monotonic() - start >= duration:
                break
            stop.wait(every_s if duration is None else min(every_s, max(0.0, duration - (time.monotonic() - start))))
            snap = telemetry.latest
            if snap.depth_m is not None:
                max_depth = snap.depth_m if max_depth is None else max(max_depth, snap.depth_m)
            if report is not None:
                report(describe(snap))
    finally:
        telemetry.stop()
        link.stop()
    result: dict[str, object] = {"latest": telemetry.latest.to_dict(), "max_depth_m": max_depth,
                                 "listened_s": round(time.monotonic() - start, 1),
                                 "link": link.stats(), "messages": telemetry.messages}
    if telemetry.rates is not None:
        result["rates"] = {name: {"asked_hz": hz, "observed_hz": round(telemetry.rates.observed_hz(name), 2),
                                  "method": telemetry.rates.method.get(name),
                                  "requests": telemetry.rates.requests[name],
                                  "missing": name in telemetry.rates.missing}
                           for name, hz in telemetry.rates.wanted.items()}
    return result
