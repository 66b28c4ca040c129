"""When a video's first frame was taken, for a summary that has no dive log (no wall clock per frame).

``merlion summarize`` on a video file knows each frame's time into the video (``time_s``) but no clock; COCO's
``date_captured`` and FathomNet's ``timestamp`` then were empty. The video file itself says when it was
recorded: its container's ``creation_time`` tag (cameras write it), read with ffprobe; a file without one started
at its modification time (when the recording ended, as the camera closed it) less its duration. Which of the two
was used is kept beside the time (``FrameRecord.date_source``), so nobody mistakes the second for a logged clock.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from datetime import datetime
from pathlib import Path

FFPROBE_TIMEOUT_S = 20.0


def _probe(path: Path) -> dict:
    ffprobe = shutil.which("ffprobe")
    if ffprobe is None:
        return {}
    try:
        out = subprocess.run([ffprobe, "-v", "error", "-show_entries", "format=duration:format_tags=creation_time",
                              "-of", "json", str(path)], capture_output=True, text=True, timeout=FFPROBE_TIMEOUT_S,
                             check=False)
        return json.loads(out.stdout or "{}").get("format", {})
    except (OSError, subprocess.SubprocessError, ValueError):
        return {}


def video_start(uri: str, folder: Path) -> tuple[float, str] | None:
    """(epoch seconds of the video's first frame, "video_creation_time" | "video_file_time"), or None when the
    video is not a file found as given or beside ``folder`` (a camera URI, a moved file)."""
    candidates = [Path(uri), folder / uri, folder.parent / Path(uri).name]
    path = next((p for p in candidates if p.is_file() and not p.is_symlink()), None)
    if path is None:
        return None
    fmt = _probe(path)
    created = (fmt.get("tags") or {}).get("creation_time")
    if isinstance(created, str) and created:
        try:
            return datetime.fromisoformat(created.replace("Z", "+00:00")).timestamp(), "video_creation_time"
        except ValueError:
            pass
    try:
        duration = float(fmt.get("duration", 0.0))
    except (TypeError, ValueError):
        duration = 0.0
    return path.stat().st_mtime - max(duration, 0.0), "video_file_time"
