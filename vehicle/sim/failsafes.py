"""The simulated ArduSub's failsafes: the pilot-input failsafe and the GCS failsafe (ArduSub's ``failsafe.cpp``).

Kept apart from the simulator's streaming and command handling so that the conditions, timers and actions can be
read in one place against ``Sub::failsafe_pilot_input_check`` and ``Sub::failsafe_gcs_check``. A new failsafe goes
here: the vehicle (``vehicle.sim.vehicle.SimVehicle``) tells ``Failsafes`` what it heard and calls ``check`` on
every tick; ``Failsafes`` acts through the few controls the vehicle lends it (``FailsafeControls``).

- pilot input: armed and MANUAL_CONTROL stopping for ``FS_PILOT_TIMEOUT`` -> "Lost manual control" (CRITICAL),
  neutral controls, and with ``FS_PILOT_INPUT`` 2 a disarm; once per loss;
- GCS: once a heartbeat (or MANUAL_CONTROL) from ``MAV_GCS_SYSID`` was seen, those stopping for
  ``FS_GCS_TIMEOUT`` -> "MYGCS: <id>, heartbeat lost" (WARNING, again every 30 s while lost) and, if armed, the
  ``FS_GCS_ENABLE`` action once per loss (2 disarm, 3 depth hold, 4 surface; 1 only warns).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.sim.messages import MODE_NUMBERS
from vehicle.sim.params import SimParams

GCS_WARN_EVERY_S = 30.0
"""While the GCS stays lost the firmware repeats its warning this often."""
PILOT_INPUT = "pilot_input"
GCS = "gcs"


class FailsafeControls(Protocol):
    """What a failsafe may read of and do to the vehicle."""

    def armed_at(self, now: float) -> bool:
        """Whether the vehicle is armed at ``now`` (its clock)."""

    def fly(self, now: float, rate_mps: float) -> None:
        """From ``now`` on, stay where it is and move vertically at ``rate_mps`` (down positive)."""

    def set_armed(self, armed: bool) -> None: ...

    def set_mode(self, custom_mode: int) -> None: ...

    def statustext(self, severity: int, text: str) -> None: ...


class Failsafes:
    """The pilot-input and GCS failsafes of one simulated vehicle: their timers, their state and their actions."""

    def __init__(self, params: SimParams, controls: FailsafeControls, clock: Callable[[], float]) -> None:
        self.params = params
        self.controls = controls
        self.clock = clock
        self.events: list[tuple[float, str]] = []
        """(seconds since start, "pilot_input" | "gcs") of every failsafe the vehicle went into."""
        self._lock = threading.Lock()
        self._start = clock()
        self._pilot_seen: float | None = None  # clock of the last MANUAL_CONTROL while armed
        self._gcs_seen: float | None = None  # clock of the last heartbeat or MANUAL_CONTROL from MAV_GCS_SYSID
        self._gcs_warned: float | None = None  # clock of the last "heartbeat lost" warning
        self._active: set[str] = set()

    def start(self, now: float) -> None:
        """The vehicle started at ``now``: events are timed from here."""
        self._start = now

    def reboot(self) -> None:
        """A reboot forgets every timer and every failsafe in force."""
        with self._lock:
            self._pilot_seen = self._gcs_seen = self._gcs_warned = None
            self._active.clear()

    @property
    def active(self) -> bool:
        """A failsafe has triggered and not cleared (the heartbeat says MAV_STATE_CRITICAL)."""
        return bool(self._active)

    # ------------------------------------------------------------------------------------------ what was heard
    def armed_changed(self) -> None:
        """The pilot-input timer starts with the first MANUAL_CONTROL after (dis)arming."""
        with self._lock:
            self._pilot_seen = None

    def pilot_input(self, now: float, armed: bool) -> None:
        """A MANUAL_CONTROL the firmware takes (from MAV_GCS_SYSID, aimed at this vehicle)."""
        with self._lock:
            if armed:
                self._pilot_seen = now
                self._active.discard(PILOT_INPUT)

    def gcs_heard(self, now: float) -> None:
        """A heartbeat (or MANUAL_CONTROL) from MAV_GCS_SYSID."""
        with self._lock:
            self._gcs_seen = now
            self._active.discard(GCS)

    # ------------------------------------------------------------------------------------------ the checks
    def check(self, now: float) -> None:
        """ArduSub's failsafe checks (its scheduler runs them at 1-10 Hz; the vehicle's tick is finer, harmless)."""
        armed = self.controls.armed_at(now)
        value = self.params.value
        pilot_action, gcs_action = int(value("FS_PILOT_INPUT")), int(value("FS_GCS_ENABLE"))
        with self._lock:
            pilot_lost = (pilot_action != 0 and armed and self._pilot_seen is not None
                          and now - self._pilot_seen > value("FS_PILOT_TIMEOUT")
                          and PILOT_INPUT not in self._active)
            gcs_lost = (gcs_action != 0 and self._gcs_seen is not None
                        and now - self._gcs_seen > value("FS_GCS_TIMEOUT"))
            gcs_warn = gcs_lost and (self._gcs_warned is None or now - self._gcs_warned > GCS_WARN_EVERY_S)
            gcs_act = gcs_lost and armed and GCS not in self._active  # once per loss, and only armed
            if pilot_lost:
                self._active.add(PILOT_INPUT)
            if gcs_warn:
                self._gcs_warned = now
            if gcs_act:
                self._active.add(GCS)
        # each action first, then the record and the message: whoever sees a failsafe sees what it did
        if pilot_lost:
            self.controls.fly(now, 0.0)  # set_neutral_controls()
            if pilot_action == 2:
                self.controls.set_armed(False)
            self.events.append((now - self._start, PILOT_INPUT))
            self.controls.statustext(mav2.MAV_SEVERITY_CRITICAL, "Lost manual control")
        if gcs_act:
            self._gcs_action(now, gcs_action)
            self.events.append((now - self._start, GCS))
        if gcs_warn:
            self.controls.statustext(mav2.MAV_SEVERITY_WARNING, f"MYGCS: {self.params.gcs_sysid()}, heartbeat lost")

    def _gcs_action(self, now: float, action: int) -> None:
        """FS_GCS_ENABLE 2: disarm, 3: depth hold (ALT_HOLD), 4: surface; 1 (and any other value) only warns."""
        if action == 2:
            self.controls.set_armed(False)
        elif action == 3:
            self.controls.set_mode(MODE_NUMBERS["ALT_HOLD"])
            self.controls.fly(now, 0.0)
        elif action == 4:  # SURFACE climbs at its own rate; PILOT_SPEED_UP stands in for it
            self.controls.set_mode(MODE_NUMBERS["SURFACE"])
            self.controls.fly(now, -self.params.pilot_speed_up_mps())
