"""A V4L2 camera (the BlueROV2's USB camera at /dev/videoN) through OpenCV's V4L2 backend.

The device is asked for the configured pixel format (MJPG keeps USB bandwidth low at high resolutions; H264 where
the camera encodes), size and rate; what the device actually granted is logged, since cameras quietly pick the
nearest mode they support.
"""

from __future__ import annotations

import logging
import re

import cv2

from companion.config import SourceConfig
from companion.sources.capture import CaptureSource

log = logging.getLogger(__name__)

V4L2_PATTERN = re.compile(r"^(/dev/video\d+|v4l2://.+|/dev/v4l/.+)$")


def is_v4l2(uri: str) -> bool:
    return bool(V4L2_PATTERN.match(uri))


def device_path(uri: str) -> str:
    return uri[len("v4l2://"):] if uri.startswith("v4l2://") else uri


def open_v4l2(cfg: SourceConfig, *, video_capture: type = cv2.VideoCapture) -> cv2.VideoCapture:
    """Open the device and ask for the configured mode (``video_capture`` is injectable: no camera in CI)."""
    path = device_path(cfg.uri)
    cap = video_capture(path, cv2.CAP_V4L2)
    if not cap.isOpened():
        return cap
    if cfg.fourcc:
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*cfg.fourcc))
    if cfg.width:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
    if cfg.height:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)
    # ask the camera for at least the rate we keep; capture thins to cfg.fps by time
    cap.set(cv2.CAP_PROP_FPS, max(cfg.fps, 15.0))
    cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a stale queue
    got_w, got_h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    code = int(cap.get(cv2.CAP_PROP_FOURCC))
    got_fourcc = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)) if code else "?"
    log.info("camera %s: %dx%d %s at %.0f fps", path, got_w, got_h, got_fourcc, cap.get(cv2.CAP_PROP_FPS))
    return cap


class V4L2Source(CaptureSource):
    def __init__(self, cfg: SourceConfig, *, video_capture: type = cv2.VideoCapture) -> None:
        super().__init__(device_path(cfg.uri), lambda: open_v4l2(cfg, video_capture=video_capture), fps=cfg.fps)
