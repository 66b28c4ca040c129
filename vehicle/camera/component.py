"""The companion as a MAVLink camera: answers discovery and capture requests, acknowledges every command.

Transport-free: ``CameraComponent.handle(msg)`` returns the messages to send (COMMAND_ACK first, then the
requested message), so the same logic is driven by the live link, by tests and by the benchmark.
Ground stations send unset COMMAND_LONG parameters as NaN; nothing here calls int() on a parameter unchecked.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.camera.capture_frame import MAX_IMAGE_INDEX
from vehicle.camera.captures import CaptureLog
from vehicle.camera.requests import addressed_to

VENDOR = "MERLION"
MSG_CAMERA_INFORMATION = 259
MSG_CAMERA_SETTINGS = 260
MSG_STORAGE_INFORMATION = 261
MSG_CAMERA_CAPTURE_STATUS = 262
MSG_CAMERA_IMAGE_CAPTURED = 263

CMD_REQUEST_MESSAGE = mav.MAV_CMD_REQUEST_MESSAGE  # 512
CMD_REQUEST_CAMERA_INFORMATION = mav.MAV_CMD_REQUEST_CAMERA_INFORMATION  # 521
CMD_REQUEST_CAMERA_CAPTURE_STATUS = mav.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS  # 527
CMD_REQUEST_CAMERA_IMAGE_CAPTURE = mav.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE  # 2002
_SUPPORTED = {CMD_REQUEST_MESSAGE, CMD_REQUEST_CAMERA_INFORMATION, CMD_REQUEST_CAMERA_CAPTURE_STATUS,
              CMD_REQUEST_CAMERA_IMAGE_CAPTURE}


def _text(value: str, size: int) -> list[int]:
    """A char[size] field that always keeps its NUL: QGroundControl reads vendor_name and model_name as C strings."""
    raw = value.encode("ascii", errors="replace")[:size - 1]
    return list(raw.ljust(size, b"\0"))


def firmware_version_of(version: str) -> int:
    """A version string packed as CAMERA_INFORMATION.firmware_version wants: Major | Minor << 8 | Patch << 16 (dev 0);
    0 when it is not numbers ("Use 0 if not known")."""
    parts = (version.split("+")[0].split("-")[0].split(".") + ["0", "0", "0"])[:3]
    if not all(p.isdigit() for p in parts):
        return 0
    major, minor, patch = (int(p) & 0xFF for p in parts)
    return major | minor << 8 | patch << 16


def param_index(value: float) -> int | None:
    """A command parameter used as an index: None when unset (NaN), negative or not a whole number."""
    if value is None or not math.isfinite(value) or value < 0 or value != int(value):
        return None
    return int(value)


@dataclass
class CameraIdentity:
    model: str = "Summary camera"
    width: int = 0
    height: int = 0
    firmware_version: int = 0
    """Packed as the spec wants (``firmware_version_of``); 0: not known. The Downlink fills in the companion's."""


class CameraComponent:
    """Answers camera-protocol requests addressed to (``system_id()``, ``component_id``).

    A broadcast request (target component 0) is answered only for the camera messages this component provides,
    so the autopilot's own answers to broadcasts are not drowned; a command addressed to this component always
    gets a COMMAND_ACK, MAV_RESULT_UNSUPPORTED when it is not one of ours.
    """

    def __init__(self, captures: CaptureLog, *, system_id: Callable[[], int], component_id: int,
                 identity: CameraIdentity | None = None) -> None:
        self.captures = captures
        self.system_id = system_id
        self.component_id = component_id
        self.identity = identity or CameraIdentity()
        self.commands_seen = 0

    # ---- the messages we provide ----------------------------------------------------------------------------

    def information(self) -> mav.MAVLink_camera_information_message:
        ident = self.identity
        return mav.MAVLink_camera_information_message(
            self.captures.time_boot_ms(), _text(VENDOR, 32), _text(ident.model, 32), ident.firmware_version,
            float("nan"), float("nan"), float("nan"), ident.width, ident.height, 0,
            mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE, 0, b"")

    def capture_status(self) -> mav.MAVLink_camera_capture_status_message:
        """image_status 0 (idle: captures come from the sampler, not a shutter); image_count counts captures, an
        int32 on the wire: once every image index was used (2^31 captures) it says 2^31-1, the most it can, rather
        than a message pymavlink cannot pack."""
        return mav.MAVLink_camera_capture_status_message(
            self.captures.time_boot_ms(), 0, 0, 0.0, 0, float("nan"), min(self.captures.image_count, MAX_IMAGE_INDEX))

    # ---- dispatch -------------------------------------------------------------------------------------------

    def handle(self, msg: mav.MAVLink_message) -> list[mav.MAVLink_message]:
        """Replies to one received COMMAND_LONG / COMMAND_INT; [] for anything not for us (standalone use: the
        downlink's ``RequestRouter`` checks the target and calls ``answer``)."""
        if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT"):
            return []
        if not addressed_to(msg, (self.system_id(), self.component_id)):
            return []
        return self.answer(msg)

    def answer(self, msg: mav.MAVLink_message) -> list[mav.MAVLink_message]:
        """Replies to a command addressed to us (or to every component: then only the camera requests)."""
        command = msg.command
        if msg.target_component == 0 and not self._answers_broadcast(msg):
            return []
        self.commands_seen += 1
        result, extra = self._run(msg)
        ack = mav.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        return [ack] + ([extra] if extra is not None else [])

    def _answers_broadcast(self, msg: mav.MAVLink_message) -> bool:
        if msg.command == CMD_REQUEST_MESSAGE:
            return param_index(msg.param1) in (MSG_CAMERA_INFORMATION, MSG_CAMERA_CAPTURE_STATUS,
                                               MSG_CAMERA_IMAGE_CAPTURED)
        return msg.command in _SUPPORTED

    def _run(self, msg: mav.MAVLink_message) -> tuple[int, mav.MAVLink_message | None]:
        command = msg.command
        if command == CMD_REQUEST_MESSAGE:
            wanted = param_index(msg.param1)
            if wanted == MSG_CAMERA_INFORMATION:
                return mav.MAV_RESULT_ACCEPTED, self.information()
            if wanted == MSG_CAMERA_CAPTURE_STATUS:
                return mav.MAV_RESULT_ACCEPTED, self.capture_status()
            if wanted == MSG_CAMERA_IMAGE_CAPTURED:
                return self._capture(msg.param2, latest_if_unset=True)
            if wanted is None:
                return mav.MAV_RESULT_DENIED, None
            return mav.MAV_RESULT_UNSUPPORTED, None
        if command == CMD_REQUEST_CAMERA_INFORMATION:
            return mav.MAV_RESULT_ACCEPTED, self.information()
        if command == CMD_REQUEST_CAMERA_CAPTURE_STATUS:
            return mav.MAV_RESULT_ACCEPTED, self.capture_status()
        if command == CMD_REQUEST_CAMERA_IMAGE_CAPTURE:
            return self._capture(msg.param1, latest_if_unset=False)
        return mav.MAV_RESULT_UNSUPPORTED, None

    def _capture(self, raw_index: float, *, latest_if_unset: bool) -> tuple[int, mav.MAVLink_message | None]:
        unset = raw_index is None or math.isnan(raw_index) or raw_index == -1
        index = param_index(raw_index)
        if index is None and not (unset and latest_if_unset):
            return mav.MAV_RESULT_DENIED, None
        found = self.captures.get(index)
        if found is None:
            return mav.MAV_RESULT_FAILED, None
        return mav.MAV_RESULT_ACCEPTED, found
