"""What the companion tells the surface about itself: event lines (STATUSTEXT) and 1 Hz values (NAMED_VALUE_FLOAT).

STATUSTEXT lines are at most 50 characters (one message, no chunking) with honest severities: QGroundControl shows
0-3 as errors and 4-5 as warnings, so routine news is INFO and only real trouble is WARNING or worse.
NAMED_VALUE_FLOAT names are at most 10 characters and avoid those QGroundControl's ArduSub support already uses.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

TEXT_MAX = 50
NAME_MAX = 10
RESERVED_NAMES = frozenset({"CamTilt", "TetherTrn", "Lights1", "Lights2", "PilotGain", "InputHold", "RollPitch",
                            "RFTarget"})

EMERGENCY, ALERT, CRITICAL, ERROR, WARNING, NOTICE, INFO, DEBUG = range(8)

# The values sent every second, and what they mean (docs/surface-link.md lists them too).
NAME_FPS = "MRL_FPS"
"""Frames per second the pipeline scores (not the camera's rate: the frame gate skips near-duplicates, and a busy
encoder drops frames; see NAME_SEEN)."""
NAME_SEEN = "MRL_SEEN"
"""Frames per second the camera (the source) delivers: MRL_FPS of these are scored."""
NAME_SCORE = "MRL_SCORE"
"""The last semantic score (positive-query share, 0-1)."""
NAME_SUMMARY = "MRL_SUMN"
"""Frames now in the summary."""
NAME_LINK = "MRL_LINKBS"
"""Bytes per second the companion put on the wire over the last seconds (link budget in use)."""
NAME_DEPTH = "MRL_DEPTH"
"""Depth in metres (positive down) of the latest pose; NaN when unknown."""
VALUE_NAMES = (NAME_FPS, NAME_SEEN, NAME_SCORE, NAME_SUMMARY, NAME_LINK, NAME_DEPTH)
NAME_PUSH = "MRL_PUSH"
"""NAMED_VALUE_INT sent right before each pushed image's handshake: the image index of the frame that follows."""


def status_text(text: str, severity: int = INFO) -> mav.MAVLink_statustext_message:
    """One STATUSTEXT, cut to 50 characters (ASCII; other characters become '?')."""
    if not 0 <= severity <= 7:
        raise ValueError(f"STATUSTEXT severity must be 0-7, got {severity}")
    raw = text.replace("\n", " ").encode("ascii", errors="replace")[:TEXT_MAX]
    return mav.MAVLink_statustext_message(severity, raw)


def named_value(name: str, value: float, time_boot_ms: int) -> mav.MAVLink_named_value_float_message:
    if len(name) > NAME_MAX or name in RESERVED_NAMES:
        raise ValueError(f"NAMED_VALUE_FLOAT name {name!r} is too long or already used by QGroundControl")
    return mav.MAVLink_named_value_float_message(time_boot_ms & 0xFFFFFFFF, name.encode("ascii"), float(value))


def push_marker(image_index: int, time_boot_ms: int) -> mav.MAVLink_named_value_int_message:
    """Pairs the next DATA_TRANSMISSION_HANDSHAKE with its capture (the image protocol has no index field)."""
    return mav.MAVLink_named_value_int_message(time_boot_ms & 0xFFFFFFFF, NAME_PUSH.encode("ascii"),
                                               int(image_index))


# ---- event lines --------------------------------------------------------------------------------------------

def started_text(version: str) -> tuple[str, int]:
    return f"MERLION {version} started", INFO


def link_text(alive: bool, first: bool = False) -> tuple[str, int]:
    """``first``: the first heartbeat since start is "up", not "back" (nothing was lost before it)."""
    if alive:
        return ("Autopilot link up" if first else "Autopilot link back"), INFO
    return "Autopilot link lost", WARNING


def camera_text(alive: bool) -> tuple[str, int]:
    return ("Camera back", INFO) if alive else ("Camera lost, retrying", WARNING)


@dataclass
class StatusValues:
    fps: float = math.nan
    seen_fps: float = math.nan
    score: float = math.nan
    summary: float = 0.0
    link_bps: float = 0.0
    depth_m: float = math.nan


class StatusReporter:
    """Holds the latest values (updated from any thread) and turns them into the 1 Hz NAMED_VALUE_FLOAT set."""

    def __init__(self, time_boot_ms: Callable[[], int]) -> None:
        self._time_boot_ms = time_boot_ms
        self._lock = threading.Lock()
        self.values = StatusValues()
        self._depth_ms: int | None = None
        """When depth_m was measured: its message carries that time, not the send tick's (up to a period later)."""

    def update(self, **values: float | None) -> None:
        """Set any of fps, seen_fps, score, summary, link_bps, depth_m; None means unknown (sent as NaN)."""
        with self._lock:
            for key, value in values.items():
                if not hasattr(self.values, key):
                    raise TypeError(f"unknown status value {key!r}")
                setattr(self.values, key, math.nan if value is None else float(value))
            if "depth_m" in values:
                self._depth_ms = self._time_boot_ms()

    def messages(self) -> list[mav.MAVLink_named_value_float_message]:
        with self._lock:
            v = StatusValues(**vars(self.values))
            depth_ms = self._depth_ms
        now = self._time_boot_ms()
        return [named_value(NAME_FPS, v.fps, now), named_value(NAME_SEEN, v.seen_fps, now),
                named_value(NAME_SCORE, v.score, now),
                named_value(NAME_SUMMARY, v.summary, now), named_value(NAME_LINK, v.link_bps, now),
                named_value(NAME_DEPTH, v.depth_m, now if depth_ms is None else depth_ms)]
