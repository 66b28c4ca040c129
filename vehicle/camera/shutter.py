"""The shutter QGroundControl shows for a camera that captures images: MAV_CMD_IMAGE_START_CAPTURE.

QGroundControl (src/Camera/VehicleCameraControl.cc: ``takePhoto``, ``_mavCommandResult``, ``handleCaptureStatus``)
sends IMAGE_START_CAPTURE (interval 0, count 1) and shows the shutter "in progress" until CAMERA_CAPTURE_STATUS
says idle: on ACCEPTED it asks for the capture status a second later, and again every second while the image
status is not idle; on TEMPORARILY_REJECTED or FAILED it retries twice, then resets the button; any other answer
(UNSUPPORTED, DENIED) leaves the button "in progress" until a CAMERA_CAPTURE_STATUS says idle (so the camera
sends one with a DENIED press: ``CameraComponent._press``). So a press is answered at once (the frame is kept
on the companion's own thread): ACCEPTED when a capture was started, TEMPORARILY_REJECTED when there is nothing to
capture yet or a capture is still being kept (one at a time: QGroundControl never presses while its button is
"in progress", so only a flood does); the capture status says "in progress" until the frame was announced, then
idle.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mav

IDLE = 0
IN_PROGRESS = 1
"""CAMERA_CAPTURE_STATUS.image_status values (0: idle, 1: capture in progress)."""

Take = Callable[[Callable[[bool], None]], bool]
"""The companion's capture: starts keeping the current frame and calls ``done(ok)`` once it was announced (or
failed); returns False when it cannot start (no frame yet)."""


class Shutter:
    """Presses in, captures started out; ``image_status`` for CAMERA_CAPTURE_STATUS."""

    def __init__(self) -> None:
        self._take: Take | None = None
        self._lock = threading.Lock()
        self._pending = 0
        self.presses = 0
        self.on_change: Callable[[], None] | None = None
        """Called when a capture finished (the Downlink sends the new capture status and storage)."""

    @property
    def wired(self) -> bool:
        """Whether a companion takes the captures (only then does CAMERA_INFORMATION offer a shutter)."""
        return self._take is not None

    def wire(self, take: Take) -> None:
        self._take = take

    @property
    def image_status(self) -> int:
        with self._lock:
            return IN_PROGRESS if self._pending else IDLE

    def press(self, msg: mav.MAVLink_message) -> int:
        """The MAV_RESULT for an IMAGE_START_CAPTURE: one image (count 1, or unset) only; a series is DENIED."""
        count = msg.param3
        if count is not None and math.isfinite(count) and count != 1:
            return mav.MAV_RESULT_DENIED  # time-lapse: the summary is the series; one frame per press
        if self._take is None:
            return mav.MAV_RESULT_UNSUPPORTED
        with self._lock:
            self.presses += 1
            if self._pending:
                return mav.MAV_RESULT_TEMPORARILY_REJECTED  # one capture at a time
            self._pending += 1
        try:
            started = self._take(self._done)
        except Exception:
            self._done(False)
            raise
        if not started:
            self._done(False)
            return mav.MAV_RESULT_TEMPORARILY_REJECTED
        return mav.MAV_RESULT_ACCEPTED

    def _done(self, _ok: bool) -> None:
        with self._lock:
            self._pending = max(0, self._pending - 1)
        if self.on_change is not None:
            self.on_change()
