"""Network video: an RTSP stream (a camera manager's) or RTP/H.264 on UDP (the BlueROV2's port 5600).

OpenCV opens RTSP directly. Plain RTP on UDP has no container, so FFmpeg needs a session description: we write a
small SDP file naming the port and the H.264 payload and open that. When OpenCV was built with GStreamer (as on
a JetPack image), a GStreamer pipeline is used instead: it decodes RTP/H.264 with lower latency.
"""

from __future__ import annotations

import logging
import os
import tempfile
import threading
from pathlib import Path

import cv2

from companion.config import SourceConfig
from companion.errors import UsageError
from companion.sources.capture import CaptureSource
from companion.sources.ffmpeg_log import quiet_ffmpeg

log = logging.getLogger(__name__)

def parse_udp(uri: str) -> tuple[str, int]:
    """``udp://@:5600`` or ``udp://0.0.0.0:5600`` -> (bind address, port)."""
    body = uri[len("udp://"):].rstrip("/")
    host, _, port = body.rpartition(":")
    host = host.lstrip("@") or "0.0.0.0"
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"source {uri!r}: expected udp://@:PORT (e.g. udp://@:5600)")
    return host, int(port)


def rtp_h264_sdp(port: int, address: str = "0.0.0.0", payload_type: int = 96) -> str:
    """The session description FFmpeg needs to receive bare RTP/H.264."""
    return (
        "v=0\r\n"
        f"o=- 0 0 IN IP4 {address}\r\n"
        "s=MERLION camera\r\n"
        f"c=IN IP4 {address}\r\n"
        "t=0 0\r\n"
        f"m=video {port} RTP/AVP {payload_type}\r\n"
        f"a=rtpmap:{payload_type} H264/90000\r\n"
    )


def has_gstreamer() -> bool:
    return any("GStreamer:" in line and "YES" in line for line in cv2.getBuildInformation().splitlines())


def gstreamer_pipeline(port: int) -> str:
    return (
        f"udpsrc port={port} caps=application/x-rtp,media=video,encoding-name=H264,payload=96 ! "
        "rtph264depay ! h264parse ! avdec_h264 ! videoconvert ! video/x-raw,format=BGR ! appsink drop=1 sync=false"
    )


FFMPEG_OPTIONS = "OPENCV_FFMPEG_CAPTURE_OPTIONS"
"""OpenCV reads FFmpeg's options from this variable at each open, for every capture in the process."""
_FFMPEG_OPTIONS_LOCK = threading.Lock()
OPEN_TIMEOUT_MS = 8000
"""Waiting for a stream to start (RTP carries SPS/PPS with key frames, a second or two apart on a BlueROV2).
Kept under health.stall_after_s (10 s) so that an absent stream is retried, not taken for a stuck process."""
READ_TIMEOUT_MS = 2500
"""A stream silent this long counts as a failed read; two in a row and it is reopened."""


def _ffmpeg_capture(target: str) -> cv2.VideoCapture:
    quiet_ffmpeg()  # a stream not there yet, a lost packet: the retrying source counts and says it, not FFmpeg
    return cv2.VideoCapture(target, cv2.CAP_FFMPEG, [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, OPEN_TIMEOUT_MS,
                                                     cv2.CAP_PROP_READ_TIMEOUT_MSEC, READ_TIMEOUT_MS])


class StreamSource(CaptureSource):
    """RTSP or RTP/UDP H.264, kept at ``cfg.fps``."""

    max_failed_reads = 2

    def __init__(self, cfg: SourceConfig) -> None:
        self.uri = cfg.uri
        self._sdp: Path | None = None
        if cfg.uri.startswith("udp://"):
            address, port = parse_udp(cfg.uri)
            if has_gstreamer():
                pipeline = gstreamer_pipeline(port)
                opener = lambda: cv2.VideoCapture(pipeline, cv2.CAP_GSTREAMER)  # noqa: E731
            else:
                fd, name = tempfile.mkstemp(prefix="merlion-", suffix=".sdp")
                with os.fdopen(fd, "w") as fh:
                    fh.write(rtp_h264_sdp(port, "127.0.0.1" if address in ("127.0.0.1", "localhost") else "0.0.0.0"))
                self._sdp = Path(name)
                opener = self._open_sdp
        else:
            opener = lambda: _ffmpeg_capture(cfg.uri)  # noqa: E731
        super().__init__(cfg.uri, opener, fps=cfg.fps)

    def _open_sdp(self) -> cv2.VideoCapture:
        """FFmpeg refuses to follow an SDP file to UDP/RTP unless those protocols are whitelisted: the option is
        set for this open only (an operator's own options win), so no other capture of the process inherits it."""
        with _FFMPEG_OPTIONS_LOCK:
            if FFMPEG_OPTIONS in os.environ:
                return _ffmpeg_capture(str(self._sdp))
            os.environ[FFMPEG_OPTIONS] = "protocol_whitelist;file,udp,rtp"
            try:
                return _ffmpeg_capture(str(self._sdp))
            finally:
                del os.environ[FFMPEG_OPTIONS]

    def close(self) -> None:
        super().close()
        if self._sdp is not None:
            self._sdp.unlink(missing_ok=True)
            self._sdp = None
