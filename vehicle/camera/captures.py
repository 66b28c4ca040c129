"""Summary frames as camera-protocol captures: CAMERA_IMAGE_CAPTURED in, STATUSTEXT for frames trimmed out.

A ground station learns of a summary frame from CAMERA_IMAGE_CAPTURED (QGroundControl drops a map marker where
lat/lon are known) and fetches it over MAVLink FTP from ``file_url``. It re-requests captures it missed by index,
so every capture stays answerable: from memory, else through the ``loader`` (the on-board store is the source of
truth across restarts).
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.autopilot.pose import Pose
from vehicle.camera.capture_frame import CaptureFrame

CAPTURE_OK = 1
CAPTURE_UNPLACED = 0
"""``capture_result`` of a capture without a valid position. QGroundControl (src/Vehicle/Vehicle.cc,
``_handleCameraImageCaptured``) puts a map marker at lat/lon for every capture with ``capture_result == 1`` and
checks nothing else: 1 with 0/0 drew a marker off West Africa. 0 is the only value it draws nothing for."""
UNKNOWN_Q = (float("nan"), 0.0, 0.0, 0.0)
"""MAVLink's way to say "attitude unknown": NaN in the first quaternion element."""


def thumbnail_path(image_index: int, ext: str = "jpg", dive: str = "") -> str:
    """``/summary/<n>.<ext>``, or ``/summary/<dive>/<n>.<ext>``: the dive makes the name unique across store
    resets (a new dive's image 0 is not the last dive's)."""
    return f"/summary/{dive}/{image_index}.{ext}" if dive else f"/summary/{image_index}.{ext}"


def file_url(image_index: int, ext: str = "jpg", dive: str = "") -> str:
    """The ``mftp://`` URL a client fetches the thumbnail from (the FTP server serves the same path)."""
    return f"mftp:/{thumbnail_path(image_index, ext, dive)}"


def quaternion(pose: Pose | None) -> tuple[float, float, float, float]:
    """w-x-y-z from the pose: its own quaternion, else from roll/pitch/yaw (ZYX), else unknown."""
    if pose is None or pose.stale:
        return UNKNOWN_Q
    if pose.q is not None:
        return tuple(float(v) for v in pose.q)  # type: ignore[return-value]
    if pose.roll is None or pose.pitch is None or pose.yaw is None:
        return UNKNOWN_Q
    cr, sr = math.cos(pose.roll / 2), math.sin(pose.roll / 2)
    cp, sp = math.cos(pose.pitch / 2), math.sin(pose.pitch / 2)
    cy, sy = math.cos(pose.yaw / 2), math.sin(pose.yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def _finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


def captured_message(frame: CaptureFrame, time_boot_ms: int, *, ext: str = "jpg", camera_id: int = 1,
                     dive: str = "") -> mav.MAVLink_camera_image_captured_message:
    """CAMERA_IMAGE_CAPTURED for a summary frame; fields the pose lacks are 0 (position) or NaN (attitude). With
    no valid position (no EKF origin, a stale pose, 0/0 once in 1e-7 degrees) ``capture_result`` is 0: QGroundControl then draws no marker,
    rather than one at 0°, 0° (docs/surface-link.md)."""
    pose = None if frame.pose is None or frame.pose.stale else frame.pose
    placed = pose is not None and _finite(pose.lat) and _finite(pose.lon) and abs(pose.lat) <= 90 \
        and abs(pose.lon) <= 180  # QGroundControl marks the map at lat/lon: both valid, or both 0 (unknown)
    lat = int(round(pose.lat * 1e7)) if placed else 0
    lon = int(round(pose.lon * 1e7)) if placed else 0
    placed = placed and (lat, lon) != (0, 0)  # 0/0 on the wire is "no position" (ArduSub's own), never a marker
    alt = int(round(pose.alt_m * 1000)) if pose is not None and _finite(pose.alt_m) else 0
    rel = int(round(-pose.depth_m * 1000)) if pose is not None and _finite(pose.depth_m) else 0
    return mav.MAVLink_camera_image_captured_message(
        time_boot_ms & 0xFFFFFFFF, int(frame.capture_time * 1e6), camera_id, lat, lon, alt, rel,
        list(quaternion(pose)), frame.image_index, CAPTURE_OK if placed else CAPTURE_UNPLACED, file_url(frame.image_index, ext, dive).encode())


def trimmed_text(frame: CaptureFrame, held: int) -> str:
    """The one-line STATUSTEXT for a frame that left the summary (50 characters at most)."""
    return f"Summary -#{frame.image_index} ({held} held)"[:50]


def added_text(frame: CaptureFrame, held: int, *, topic: bool = False) -> str:
    """``topic``: name the frame's topic (when several are followed, the operator needs to know which)."""
    depth = frame.pose.depth_m if frame.pose is not None and not frame.pose.stale else None
    where = f" {depth:.1f}m" if _finite(depth) else ""
    which = f" {frame.topic}" if topic and getattr(frame, "topic", "") else ""
    return f"Summary +#{frame.image_index}{which} ss={frame.score:.2f}{where} ({held} held)"[:50]


class CaptureLog:
    """Every capture announced, by image index, answerable again on request.

    ``image_count`` starts from what the store already holds (``initial_count``), so it counts summary frames
    ever taken, across restarts. Messages stay in memory up to ``keep``; older ones come from ``loader``.
    """

    def __init__(self, *, clock: Callable[[], float] = time.monotonic, initial_count: int = 0,
                 loader: Callable[[int], CaptureFrame | None] | None = None, keep: int = 2000,
                 ext: str = "jpg", dive: str = "") -> None:
        self._clock = clock
        self.dive = dive
        self._t0 = clock()
        self._lock = threading.Lock()
        self._messages: OrderedDict[int, mav.MAVLink_camera_image_captured_message] = OrderedDict()
        self._loader = loader
        self._keep = keep
        self.ext = ext
        self.image_count = initial_count
        self.last_index: int | None = None

    def time_boot_ms(self) -> int:
        """Milliseconds since this companion component started (its own boot clock)."""
        return int((self._clock() - self._t0) * 1000)

    def record(self, frame: CaptureFrame, *, count: bool = True) -> mav.MAVLink_camera_image_captured_message:
        """Keep the capture message of a summary frame for re-requests; ``count`` it unless an earlier run did."""
        msg = captured_message(frame, self.time_boot_ms(), ext=self.ext, dive=self.dive)
        with self._lock:
            self._messages[frame.image_index] = msg
            self._messages.move_to_end(frame.image_index)
            while len(self._messages) > self._keep:
                self._messages.popitem(last=False)
            if count:
                self.image_count += 1
            self.last_index = frame.image_index if self.last_index is None else max(self.last_index,
                                                                                  frame.image_index)
        return msg

    def get(self, image_index: int | None) -> mav.MAVLink_camera_image_captured_message | None:
        """The capture with that index (None: the latest), or None when neither memory nor store has it."""
        with self._lock:
            if image_index is None:
                image_index = self.last_index
            if image_index is None:
                return None
            msg = self._messages.get(image_index)
        if msg is not None or self._loader is None:
            return msg
        frame = self._loader(image_index)
        return None if frame is None else captured_message(frame, self.time_boot_ms(), ext=self.ext, dive=self.dive)
