"""Issue 48's spoofer: an unsigned peer claiming to be the autopilot (system 1, component 1) with made-up telemetry.

Twenty times a second it sends HEARTBEAT (type 12 submarine, autopilot 3), GLOBAL_POSITION_INT (123.4 m deep,
latitude -33.0), SCALED_PRESSURE2 (the pressure at 123.4 m), VFR_HUD (altitude -123.4 m) and ATTITUDE (roll 1.0 rad),
each in MAVLink 2 and in MAVLink 1 framing (``framings``), from its own UDP socket to ``target``. ``is_spoofed``
tells a pose or a telemetry snapshot that carries any of its values.
"""

from __future__ import annotations

import math
import socket
import threading
import time

from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2

DEPTH_M = 123.4
LAT = -33.0
ROLL = 1.0
PRESSURE_HPA = 1013.25 + DEPTH_M * 1025.0 * 9.80665 / 100.0


def _messages(dialect, boot_ms: int) -> list:
    return [
        dialect.MAVLink_heartbeat_message(dialect.MAV_TYPE_SUBMARINE, dialect.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                          dialect.MAV_MODE_FLAG_SAFETY_ARMED, 19, 4, 3),
        dialect.MAVLink_global_position_int_message(boot_ms, int(LAT * 1e7), int(151.2 * 1e7), -int(DEPTH_M * 1000),
                                                    -int(DEPTH_M * 1000), 0, 0, 0, 9000),
        dialect.MAVLink_scaled_pressure2_message(boot_ms, PRESSURE_HPA, 0.0, 1500),
        dialect.MAVLink_vfr_hud_message(0.0, 0.0, 90, 0, -DEPTH_M, 0.0),
        dialect.MAVLink_attitude_message(boot_ms, ROLL, 0.0, math.pi / 2, 0.0, 0.0, 0.0),
    ]


class Spoofer:
    """Sends the made-up autopilot stream at ``hz`` on a thread from ``start()`` to ``stop()``."""

    def __init__(self, target: tuple[str, int], *, hz: float = 20.0, framings: tuple[int, ...] = (2, 1)) -> None:
        self.target = target
        self.period = 1.0 / hz
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.packers = [(mav2, mav2.MAVLink(None, 1, 1)) if f == 2 else (mav1, mav1.MAVLink(None, 1, 1))
                        for f in framings]
        self.sent = 0
        self.started_at: float | None = None
        self._born = time.monotonic() - 600.0  # "up ten minutes": its own time_boot_ms, unlike the real one
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="spoofer", daemon=True)

    def start(self) -> Spoofer:
        self.started_at = time.monotonic()
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            boot_ms = int((time.monotonic() - self._born) * 1000)
            for dialect, packer in self.packers:
                for msg in _messages(dialect, boot_ms):
                    try:
                        self.sock.sendto(msg.pack(packer), self.target)
                    except OSError:  # nobody listening yet (the port not bound): the datagram is lost, as on a wire
                        pass
                    self.sent += 1
            self._stop.wait(self.period)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self.sock.close()


def is_spoofed(values: dict) -> bool:
    """Whether a pose or telemetry snapshot (as a dict) carries the spoofer's depth, position or attitude."""
    depth, lat, roll = values.get("depth_m"), values.get("lat"), values.get("roll")
    return ((depth is not None and abs(depth - DEPTH_M) < 1.0) or (lat is not None and abs(lat - LAT) < 0.01)
            or (roll is not None and abs(roll - ROLL) < 0.01))
