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

from companion.errors import UsageError
from companion.export.frame_entry import FrameEntry


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

    @property
    def best_utc(self) -> str | None:
        """The autopilot's time where it has one (it survives a wrong companion clock), else the companion's."""
        return self.autopilot_utc or self.capture_utc


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
            "heading_deg": _number(pose.get("heading_deg")), "roll_deg": _degrees(pose.get("roll")),
            "pitch_deg": _degrees(pose.get("pitch")), "yaw_deg": _degrees(pose.get("yaw")), "lat": lat, "lon": lon,
            "autopilot_utc": iso_utc(unix_us / 1e6) if unix_us else None,
            "time_boot_ms": int(boot) if boot is not None else None}


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise UsageError(f"{path}: not readable JSON ({err})") from None


def _image_size(path: Path) -> tuple[int, int]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
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
            **_pose_fields(side.get("pose"))))
    return out


def _summary_records(folder: Path, doc: dict, dive: str) -> list[FrameRecord]:
    params = doc.get("params") if isinstance(doc.get("params"), dict) else {}
    topics = params.get("topics") or [{"name": "", "query": params.get("query", "")}]
    queries = {str(t.get("name", "")): str(t.get("query", "")) for t in topics if isinstance(t, dict)}
    tags_path = folder / "tags.json"
    tags = _read_json(tags_path) if tags_path.exists() else {}
    by_index = {f.get("index"): f for f in tags.get("frames", []) if isinstance(f, dict)} \
        if isinstance(tags, dict) else {}
    out = []
    for position, data in enumerate(doc.get("frames") or []):
        entry = FrameEntry(folder / "summary.json", position, data)
        image = entry.image(folder)
        width, height = _image_size(image)
        tag = by_index.get(data.get("index"), {})
        topic = entry.text("topic")
        out.append(FrameRecord(
            image=image, dive=dive, frame=entry.whole("index", position), width=width, height=height,
            score=entry.number("score", 0.0), topic=topic,
            query=queries.get(topic, str(params.get("query", ""))), time_s=_number(data.get("time_s")),
            capture_utc=iso_utc(_number(tag.get("wall_time"))), source=entry.text("source") or None,
            **_pose_fields(tag.get("pose"))))
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
        dive = folder / name
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
