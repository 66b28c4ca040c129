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
from vehicle.camera.shutter import Shutter
from vehicle.camera.storage import StorageSpace, available_mib, storage_information

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
CMD_REQUEST_STORAGE_INFORMATION = mav.MAV_CMD_REQUEST_STORAGE_INFORMATION  # 525
CMD_IMAGE_START_CAPTURE = mav.MAV_CMD_IMAGE_START_CAPTURE  # 2000
CMD_IMAGE_STOP_CAPTURE = mav.MAV_CMD_IMAGE_STOP_CAPTURE  # 2001
_BROADCAST_MESSAGES = (MSG_CAMERA_INFORMATION, MSG_STORAGE_INFORMATION, MSG_CAMERA_CAPTURE_STATUS,
                       MSG_CAMERA_IMAGE_CAPTURED)
_BROADCAST_COMMANDS = {CMD_REQUEST_MESSAGE, CMD_REQUEST_CAMERA_INFORMATION, CMD_REQUEST_CAMERA_CAPTURE_STATUS,
                       CMD_REQUEST_CAMERA_IMAGE_CAPTURE, CMD_REQUEST_STORAGE_INFORMATION}
"""Requests answered also when sent to every component (the shutter only when addressed to us)."""
Reply = tuple[int, "mav.MAVLink_message | None"]


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
        self.shutter = Shutter()
        """MAV_CMD_IMAGE_START_CAPTURE: the pilot's own capture, once the companion wired it (``Shutter.wire``)."""
        self.storage: Callable[[], StorageSpace | None] = lambda: None
        """The store's room now (the companion's ``Store.space``); None: no store."""
        self._commands: dict[int, Callable[[mav.MAVLink_message], Reply]] = {
            CMD_REQUEST_MESSAGE: self._request_message,
            CMD_REQUEST_CAMERA_INFORMATION: lambda _m: (mav.MAV_RESULT_ACCEPTED, self.information()),
            CMD_REQUEST_CAMERA_CAPTURE_STATUS: lambda _m: (mav.MAV_RESULT_ACCEPTED, self.capture_status()),
            CMD_REQUEST_STORAGE_INFORMATION: self._request_storage,
            CMD_REQUEST_CAMERA_IMAGE_CAPTURE: lambda m: self._capture(m.param1, latest_if_unset=False),
            CMD_IMAGE_START_CAPTURE: self._press,
            CMD_IMAGE_STOP_CAPTURE: lambda _m: (mav.MAV_RESULT_ACCEPTED, None),  # one image per press: none running
        }
        """Command -> its handler: the one table of what this camera does (anything else is UNSUPPORTED)."""

    # ---- the messages we provide ----------------------------------------------------------------------------

    def information(self) -> mav.MAVLink_camera_information_message:
        ident = self.identity
        return mav.MAVLink_camera_information_message(
            self.captures.time_boot_ms(), _text(VENDOR, 32), _text(ident.model, 32), ident.firmware_version,
            float("nan"), float("nan"), float("nan"), ident.width, ident.height, 0,
            mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE if self.shutter.wired else 0, 0, b"")

    def capture_status(self) -> mav.MAVLink_camera_capture_status_message:
        """image_status 1 while a pilot's capture is being kept, else 0 (idle: QGroundControl resets its shutter
        button on it); available_capacity the store's room left in MiB (never NaN: QGroundControl casts it to
        uint32); image_count counts captures, an int32 on the wire: once every image index was used (2^31
        captures) it says 2^31-1, the most it can, rather than a message pymavlink cannot pack."""
        return mav.MAVLink_camera_capture_status_message(
            self.captures.time_boot_ms(), self.shutter.image_status, 0, 0.0, 0, available_mib(self.storage()),
            min(self.captures.image_count, MAX_IMAGE_INDEX))

    def storage_information(self) -> mav.MAVLink_storage_information_message:
        return storage_information(self.storage(), self.captures.time_boot_ms())

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
            return param_index(msg.param1) in _BROADCAST_MESSAGES
        return msg.command in _BROADCAST_COMMANDS

    def _run(self, msg: mav.MAVLink_message) -> Reply:
        handler = self._commands.get(msg.command)
        return (mav.MAV_RESULT_UNSUPPORTED, None) if handler is None else handler(msg)

    def _request_message(self, msg: mav.MAVLink_message) -> Reply:
        wanted = param_index(msg.param1)
        if wanted == MSG_CAMERA_INFORMATION:
            return mav.MAV_RESULT_ACCEPTED, self.information()
        if wanted == MSG_CAMERA_CAPTURE_STATUS:
            return mav.MAV_RESULT_ACCEPTED, self.capture_status()
        if wanted == MSG_STORAGE_INFORMATION:
            return self._storage_for(msg.param2)
        if wanted == MSG_CAMERA_IMAGE_CAPTURED:
            return self._capture(msg.param2, latest_if_unset=True)
        if wanted is None:
            return mav.MAV_RESULT_DENIED, None
        return mav.MAV_RESULT_UNSUPPORTED, None

    def _press(self, msg: mav.MAVLink_message) -> Reply:
        """The shutter's answer; a DENIED press (a time-lapse series) comes with the capture status. QGroundControl
        (``_mavCommandResult``) resets its button only on ACCEPTED-then-idle or after retrying TEMPORARILY_REJECTED
        or FAILED; DENIED it logs as a bad response and the button stays "in progress", but any
        CAMERA_CAPTURE_STATUS (``handleCaptureStatus``) sets it to what the status says: idle."""
        result = self.shutter.press(msg)
        return result, self.capture_status() if result == mav.MAV_RESULT_DENIED else None

    def _request_storage(self, msg: mav.MAVLink_message) -> Reply:
        """MAV_CMD_REQUEST_STORAGE_INFORMATION: p1 the storage id (0: all), p2 1 to ask."""
        return self._storage_for(msg.param1)

    def _storage_for(self, raw_id: float) -> Reply:
        """Storage 0 (all), 1 (ours) or unset: its STORAGE_INFORMATION; any other id: DENIED (there is none)."""
        wanted = param_index(raw_id)
        if raw_id is not None and not math.isnan(raw_id) and wanted not in (0, 1):
            return mav.MAV_RESULT_DENIED, None
        return mav.MAV_RESULT_ACCEPTED, self.storage_information()

    def _capture(self, raw_index: float, *, latest_if_unset: bool) -> Reply:
        unset = raw_index is None or math.isnan(raw_index) or raw_index == -1
        index = param_index(raw_index)
        if index is None and not (unset and latest_if_unset):
            return mav.MAV_RESULT_DENIED, None
        found = self.captures.get(index)
        if found is None:
            return mav.MAV_RESULT_FAILED, None
        return mav.MAV_RESULT_ACCEPTED, found
