"""What FFmpeg and OpenCV print on their own when a capture opens: kept off stderr, where our one-line error goes.

FFmpeg logs through C straight to stderr ("moov atom not found" for a file that is not a video), and OpenCV adds
its own warning when no backend could open the target. A source that fails says so itself, once
(``merlion: error: FILE: cannot be opened as a video``), so both are held back around our opens:

- FFmpeg's level is read once per process, when OpenCV first starts FFmpeg; ``OPENCV_FFMPEG_LOGLEVEL`` is set to
  fatal before that (``quiet_ffmpeg``) unless the operator chose a level (``OPENCV_FFMPEG_LOGLEVEL=24`` shows its
  warnings again, ``OPENCV_FFMPEG_DEBUG=1`` everything);
- OpenCV's level is process-wide and can change at any time: it is raised to ERROR for the open only, under a
  lock (``opening``), unless ``OPENCV_LOG_LEVEL`` says otherwise.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

import cv2

FFMPEG_LOGLEVEL = "OPENCV_FFMPEG_LOGLEVEL"
AV_LOG_FATAL = 8
"""FFmpeg's level for "something went wrong and recovery is not possible": all it may still print."""
_OPEN_LOCK = threading.Lock()


def quiet_ffmpeg() -> None:
    """Keep FFmpeg to fatal messages (before its first use in the process; an operator's own level wins)."""
    if "OPENCV_FFMPEG_DEBUG" not in os.environ:
        os.environ.setdefault(FFMPEG_LOGLEVEL, str(AV_LOG_FATAL))


@contextlib.contextmanager
def opening() -> Iterator[None]:
    """Around one ``cv2.VideoCapture`` open through FFmpeg: its own lines and OpenCV's open warning held back."""
    quiet_ffmpeg()
    if "OPENCV_LOG_LEVEL" in os.environ:
        yield
        return
    with _OPEN_LOCK:
        before = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(min(before, cv2.utils.logging.LOG_LEVEL_ERROR))
        try:
            yield
        finally:
            cv2.utils.logging.setLogLevel(before)
