"""Read the summary frames of an on-board store, a ``merlion summarize`` folder or an archive campaign, as one
flat record per frame that every export format writes from.

Each input keeps its frames differently: the store has a JSON sidecar per frame (pose, times, tags) listed in its
``summary.json``; a summarize folder has ``summary.json`` (frames, topics and queries) and, when the archive matched
a dive log, ``tags.json`` (pose and wall time per frame); a campaign folder has ``manifest.json`` naming its
finished dives. Bad input is a ``UsageError`` naming the file; nothing read is ever written.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.errors import UsageError
from companion.export.frame_entry import FrameEntry
from companion.export.video_time import video_start
from companion.storage.frame_files import read_no_link


@dataclass(frozen=True)
class FrameRecord:
    """One summary frame with everything an export may carry (None: not known)."""

    image: Path
    dive: str
    frame: int
    """The frame's index: the image index on board, the frame number in the video for a summarize folder."""
    width: int
    height: int
    score: float
    topic: str
    query: str
    time_s: float | None = None
    """Seconds into the video (summarize, archive) or since the companion started (store)."""
    capture_utc: str | None = None
    """The companion's clock at capture, UTC ISO 8601."""
    autopilot_utc: str | None = None
    """The autopilot's clock at capture (SYSTEM_TIME carried on its boot clock), UTC ISO 8601."""
    time_boot_ms: int | None = None
    depth_m: float | None = None
    altitude_m: float | None = None
    """Above mean sea level, as the autopilot reports it (GLOBAL_POSITION_INT.alt), not above the seabed."""
    heading_deg: float | None = None
    roll_deg: float | None = None
    pitch_deg: float | None = None
    yaw_deg: float | None = None
    lat: float | None = None
    """Only when valid: the autopilot had a position origin, in range, not 0/0."""
    lon: float | None = None
    source: str | None = None
    """The still's own file name, for a summary of an image folder (``summary.json`` frames' ``source``)."""
    video: str | None = None
    """The video the frame was taken from (a summarize/archive folder's ``source``; ``time_s`` is into it)."""
    threshold: float | None = None
    """The threshold (tau_ss) the score is read against, where the input records it."""
    stand_in: bool = False
    """Shown although nothing passed the threshold (``vision.below_threshold``)."""
    pilot: bool = False
    """Kept by the pilot's shutter, whatever its score (``vision.pilot_capture``)."""
    water_temp_c: float | None = None
    """Water temperature from the autopilot's external pressure sensor (SCALED_PRESSURE2: the Bar30)."""
    pressure_dbar: float | None = None
    """Absolute water pressure there, in decibar (FathomNet's ``pressureDbar``)."""
    video_utc: str | None = None
    """The frame's time from the video file (offline summaries without a dive log): its start plus ``time_s``."""
    video_time_source: str | None = None
    """How the video's start is known: video_creation_time (its container tag) | video_file_time (its file)."""

    @property
    def below_threshold(self) -> bool:
        """Not a match of the query: a stand-in, or (a pilot's frame) a score at or under the threshold."""
        return self.stand_in or (self.threshold is not None and self.score <= self.threshold)

    @property
    def best_utc(self) -> str | None:
        """The autopilot's time where it has one (it survives a wrong companion clock), else the companion's, else
        the video file's creation time plus the frame's time into it."""
        return self.autopilot_utc or self.capture_utc or self.video_utc

    @property
    def date_source(self) -> str | None:
        """Which clock ``best_utc`` is: autopilot | companion | video_creation_time | video_file_time."""
        for name, value in (("autopilot", self.autopilot_utc), ("companion", self.capture_utc),
                            (self.video_time_source, self.video_utc)):
            if value:
                return name
        return None


def iso_utc(t: float | None) -> str | None:
    """Seconds since the epoch as UTC ISO 8601 with milliseconds and a Z."""
    if t is None or not math.isfinite(t) or t <= 0:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _degrees(radians: Any) -> float | None:
    value = _number(radians)
    return None if value is None else math.degrees(value)


def _heading(value: Any) -> float | None:
    """A heading in [0, 360), also once written with 2 decimals (359.999 would print as 360.00)."""
    h = _number(value)
    if h is None:
        return None
    h %= 360.0
    return 0.0 if round(h, 2) >= 360.0 else h


def _water(pose: dict) -> dict[str, float | None]:
    """Water temperature (degC) and pressure (dbar) of a pose that has them (SCALED_PRESSURE2)."""
    hpa = _number(pose.get("pressure_hpa"))
    return {"water_temp_c": _number(pose.get("water_temp_c")),
            "pressure_dbar": None if hpa is None else round(hpa / 100.0, 4)}


def _valid_position(lat: Any, lon: Any) -> tuple[float | None, float | None]:
    la, lo = _number(lat), _number(lon)
    if la is None or lo is None or not (-90 <= la <= 90 and -180 <= lo <= 180) or (la == 0 and lo == 0):
        return None, None
    return la, lo


def _pose_fields(pose: dict | None) -> dict[str, Any]:
    pose = pose if isinstance(pose, dict) else {}
    if pose.get("stale"):
        pose = {k: pose.get(k) for k in ("time_boot_ms", "autopilot_unix_usec")}  # only the clocks still hold
    lat, lon = _valid_position(pose.get("lat"), pose.get("lon"))
    unix_us = _number(pose.get("autopilot_unix_usec"))
    boot = _number(pose.get("time_boot_ms"))
    return {"depth_m": _number(pose.get("depth_m")), "altitude_m": _number(pose.get("alt_m")),
            "heading_deg": _heading(pose.get("heading_deg")), "roll_deg": _degrees(pose.get("roll")),
            "pitch_deg": _degrees(pose.get("pitch")), "yaw_deg": _degrees(pose.get("yaw")), "lat": lat, "lon": lon,
            "autopilot_utc": iso_utc(unix_us / 1e6) if unix_us else None,
            "time_boot_ms": int(boot) if boot is not None else None, **_water(pose)}


def _read_json(path: Path) -> Any:
    """A store's or summary's own JSON; a symbolic link is refused (it would read, and export, another folder's)."""
    if path.is_symlink():
        raise UsageError(f"{path}: a symbolic link; an export follows none")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise UsageError(f"{path}: not readable JSON ({err})") from None


def image_bytes(path: Path) -> bytes:
    """A frame's bytes as checked (``FrameEntry.image``), opened with ``O_NOFOLLOW``: a frame swapped for a link
    after its check is refused, never hashed or measured through the link."""
    data = read_no_link(path)
    if data is None:
        raise UsageError(f"{path}: not read (missing, unreadable or a symbolic link); an export follows no link")
    return data


def _image_size(path: Path) -> tuple[int, int]:
    image = cv2.imdecode(np.frombuffer(image_bytes(path), np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise UsageError(f"{path}: frame image missing or not an image")
    return int(image.shape[1]), int(image.shape[0])


def _store_records(folder: Path, doc: dict) -> list[FrameRecord]:
    dive = str(doc.get("dive") or folder.name)
    out = []
    for position, side in enumerate(doc.get("frames") or []):
        entry = FrameEntry(folder / "summary.json", position, side)
        image = entry.image(folder)
        tags = side.get("tags") if isinstance(side.get("tags"), dict) else {}
        width, height = entry.size("width"), entry.size("height")
        if width is None or height is None:
            width, height = _image_size(image)
        out.append(FrameRecord(
            image=image, dive=dive, frame=entry.whole("image_index", position), width=width, height=height,
            score=entry.number("score", 0.0), topic=entry.text("topic"), query=entry.text("query", tags),
            time_s=_number(side.get("time_s")), capture_utc=iso_utc(_number(side.get("capture_time"))),
            threshold=_number(tags.get("tau_ss")), stand_in=side.get("below_threshold") is True,
            pilot=side.get("pilot") is True, **_pose_fields(side.get("pose"))))
    return out


def _summary_records(folder: Path, doc: dict, dive: str) -> list[FrameRecord]:
    params = doc.get("params") if isinstance(doc.get("params"), dict) else {}
    topics = params.get("topics") or [{"name": "", "query": params.get("query", ""), "tau_ss": params.get("tau_ss")}]
    queries = {str(t.get("name", "")): str(t.get("query", "")) for t in topics if isinstance(t, dict)}
    taus = {str(t.get("name", "")): _number(t.get("tau_ss", params.get("tau_ss"))) for t in topics
            if isinstance(t, dict)}
    video = doc.get("source") if isinstance(doc.get("source"), str) and doc.get("source") else None
    started = video_start(video, folder) if video else None
    tags_path = folder / "tags.json"
    tags = _read_json(tags_path) if tags_path.exists() or tags_path.is_symlink() else {}
    by_index = {f.get("index"): f for f in tags.get("frames", []) if isinstance(f, dict)} \
        if isinstance(tags, dict) else {}
    out = []
    for position, data in enumerate(doc.get("frames") or []):
        entry = FrameEntry(folder / "summary.json", position, data)
        image = entry.image(folder)
        width, height = _image_size(image)
        tag = by_index.get(data.get("index"), {})
        topic = entry.text("topic")
        still = entry.text("source") or None
        time_s = _number(data.get("time_s"))
        out.append(FrameRecord(
            image=image, dive=dive, frame=entry.whole("index", position), width=width, height=height,
            score=entry.number("score", 0.0), topic=topic,
            query=queries.get(topic, str(params.get("query", ""))), time_s=time_s,
            capture_utc=iso_utc(_number(tag.get("wall_time"))), source=still,
            video=None if still else video, threshold=taus.get(topic, _number(params.get("tau_ss"))),
            stand_in=data.get("below_threshold") is True,
            video_utc=iso_utc(started[0] + time_s) if started and time_s is not None and not still else None,
            video_time_source=started[1] if started else None, **_pose_fields(tag.get("pose"))))
    return out


def campaign_records(folder: Path, names: list[str] | None = None) -> list[FrameRecord]:
    """The frames of a campaign's dives ``names`` (default: every finished dive of its manifest)."""
    if names is None:
        manifest = _read_json(folder / "manifest.json")
        finished = manifest.get("finished") if isinstance(manifest, dict) else None
        if not isinstance(finished, dict):
            raise UsageError(f"{folder / 'manifest.json'}: not a campaign manifest (no 'finished')")
        names = sorted(finished)
    out: list[FrameRecord] = []
    for name in names:
        dive = folder / str(name)
        if not isinstance(name, str) or name in ("", ".", "..") or Path(name).name != name:
            raise UsageError(f"{folder / 'manifest.json'}: dive {str(name)!r:.60} is not a folder of the campaign")
        if dive.is_symlink():
            raise UsageError(f"{dive}: a symbolic link; an export follows none")
        out.extend(_summary_records(dive, _read_json(dive / "summary.json"), name))
    return out


def read_records(source: str | Path) -> list[FrameRecord]:
    """The summary frames at ``source`` (a store, a summarize folder or its summary.json, a campaign folder),
    in dive then time order."""
    path = Path(source)
    if path.is_file() and path.name == "summary.json":
        path = path.parent
    if path.is_file():
        raise UsageError(f"{source}: a file, not a store, summary or campaign folder (give the folder that "
                         f"merlion summarize, archive or run wrote)")
    if not path.is_dir():
        raise UsageError(f"{source}: not a store, summary or campaign folder (no such folder)")
    if (path / "manifest.json").is_file():
        return campaign_records(path)
    summary = path / "summary.json"
    if not summary.is_file():
        raise UsageError(f"{source}: no summary.json (not a store, summary or campaign folder)")
    doc = _read_json(summary)
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise UsageError(f"{summary}: no 'frames' list (not a MERLION summary)")
    if "params" in doc:
        return _summary_records(path, doc, path.name)
    return sorted(_store_records(path, doc), key=lambda r: r.frame)  # image indices are handed out in time order
