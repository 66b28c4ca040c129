"""Turns what the companion says (CAMERA_IMAGE_CAPTURED, STATUSTEXT, /summary/index.json) into surface facts.

The parsers are deliberately tolerant: the companion's wording of status lines and the exact keys of its index
file may change between versions, and a surface tool that ignores a line it half understands is better than one
that crashes on it. What is not understood here is left to the next index.json pull, which is authoritative.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field

from companion.topside.capture import Capture, Topic, safe_dive
from companion.topside.gallery import MAX_SUMMARY
from vehicle.autopilot.telemetry import NO_POSITION_TEXT, POSITION_FOUND_TEXT
from vehicle.protocol.queries import MAX_LINE, MAX_NEGATIVES, MAX_TOPICS, NAME

TAKES_BACK = {POSITION_FOUND_TEXT: NO_POSITION_TEXT}
"""A status line that clears a condition -> the line that had said it: once the first comes, the page stops
showing the second (positions arriving after "no position source" was said)."""

MAX_URL = 205
"""Characters of a ``file_url`` kept (CAMERA_IMAGE_CAPTURED's field holds 205): a longer one from index.json is
dropped, as is a topic that is not a topic name; each was kept for every capture in gallery.json."""


def heading_from_q(q: list[float] | tuple[float, ...]) -> float | None:
    """Yaw of a w-x-y-z quaternion as a compass heading in [0, 360); None for a zero or NaN quaternion."""
    if len(q) != 4 or any(not math.isfinite(v) for v in q):
        return None
    w, x, y, z = q
    if w * w + x * x + y * y + z * z < 1e-6:
        return None
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return compass(math.degrees(yaw))


def compass(degrees: float) -> float:
    """A heading in [0, 360) to a tenth of a degree (359.99 is 0.0, not 360.0)."""
    return round(degrees % 360.0, 1) % 360.0


def mftp_path(url: str) -> str | None:
    """``mftp://summary/3.jpg`` (or ``mftp:///summary/3.jpg``) -> ``/summary/3.jpg``; None if not an mftp URL."""
    if not url.startswith("mftp://"):
        return None
    rest = url[len("mftp://") :].lstrip("/")
    return "/" + rest if rest else None


_DIVE = re.compile(r"/summary/([^/]+)/\d+\.\w+$")


def dive_of(url: str | None) -> str | None:
    """The dive id in a thumbnail URL (``mftp://summary/<dive>/<n>.jpg``); None when it names none; ValueError
    when what stands there is not a safe name (``capture.safe_dive``: it becomes a folder in DIR)."""
    match = _DIVE.search(url or "")
    return safe_dive(match.group(1)) if match and match.group(1) not in ("full", "raw") else None


def capture_from_message(msg) -> Capture:
    """CAMERA_IMAGE_CAPTURED -> Capture. Depth comes from relative_alt (mm, negative underwater)."""
    q = [float(v) for v in msg.q]
    url = msg.file_url
    if isinstance(url, bytes):
        url = url.decode("utf-8", "replace")
    url = url.rstrip("\0") or None
    lat = msg.lat / 1e7 if msg.lat else None
    lon = msg.lon / 1e7 if msg.lon else None
    return Capture(
        image_index=int(msg.image_index),
        dive=dive_of(url),
        time_utc=msg.time_utc / 1e6 if msg.time_utc else None,
        depth_m=round(-msg.relative_alt / 1000.0, 3),
        heading_deg=heading_from_q(q),
        q=q if heading_from_q(q) is not None else None,
        lat=lat, lon=lon,
        alt_m=msg.alt / 1000.0 if msg.alt and lat is not None else None,
        file_url=url,
    )


@dataclass
class StatusFacts:
    """What a STATUSTEXT line told us about the summary."""

    removed: list[int] = field(default_factory=list)
    added: list[int] = field(default_factory=list)
    scores: dict[int, float] = field(default_factory=dict)
    topics: dict[int, str] = field(default_factory=dict)
    """The topic an added frame entered (``Summary +#7 fish ss=0.83 ...``: named when several are followed)."""
    summary_changed: bool = False
    """The line is about the summary but we could not read which frames: pull index.json to be sure."""


_REMOVED = re.compile(r"\b(?:trim\w*|remov\w*|drop\w*|evict\w*|out)\b", re.I)
_ADDED = re.compile(r"\b(?:add\w*|new|kept|keep|captur\w*|in)\b", re.I)
_INDEX = re.compile(r"(?:#|\b(?:img|image|idx|index|frame|n)\s*[:=#]?\s*)(\d+)", re.I)
_SCORE = re.compile(r"\b(?:score|ss|s)\s*[:=]?\s*(-?\d+(?:\.\d+)?)", re.I)
_TOPIC = re.compile(r"\+#\d+ ([a-z0-9][a-z0-9_-]{0,23}) ss=")
"""A topic name (vehicle/protocol/queries.py's rule) between the index and the score; a name the 50-character
line cut short is not followed by `` ss=``, so it is never taken for another topic."""


def parse_statustext(text: str) -> StatusFacts:
    """Read summary events from a status line, e.g. ``summary -#12 (trimmed)`` or ``added #7 score 0.83``."""
    facts = StatusFacts()
    if text.startswith(("Queries set", "Topics set")):  # new topics: index.json lists them (and drops frames)
        facts.summary_changed = True
        return facts
    if not any(w in text.lower() for w in ("summ", "trim", "remov", "drop", "evict", "add", "img", "image", "#")):
        return facts
    indices = [int(m) for m in _INDEX.findall(text)]
    signed = [(sign, int(n)) for sign, n in re.findall(r"([+-])#(\d+)\b", text)]
    if signed:
        facts.added = [n for s, n in signed if s == "+"]
        facts.removed = [n for s, n in signed if s == "-"]
        score = _SCORE.search(text)
        if score and len(facts.added) == 1:
            facts.scores[facts.added[0]] = float(score.group(1))
        topic = _TOPIC.search(text)
        if topic and len(facts.added) == 1:
            facts.topics[facts.added[0]] = topic.group(1)
    elif indices and _REMOVED.search(text):
        facts.removed = indices
    elif indices and _ADDED.search(text):
        facts.added = indices
        score = _SCORE.search(text.split("#", 1)[-1]) if "#" in text else _SCORE.search(text)
        if score and len(indices) == 1:
            facts.scores[indices[0]] = float(score.group(1))
    if "summ" in text.lower() and not (facts.removed or facts.added):
        facts.summary_changed = True
    return facts


def _first(d: dict, *keys):
    for k in keys:
        if k in d and d[k] is not None:
            return d[k]
    return None


def _num(value) -> float | None:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def _epoch_s(value) -> float | None:
    """Seconds since epoch from seconds, milliseconds or microseconds (senders differ)."""
    t = _num(value)
    if t is None:
        return None
    while t > 1e11:
        t /= 1000.0
    return t


def index_dive(data: bytes) -> str | None:
    """The dive id an index.json names (top-level ``dive``), else None; ValueError when it is not a safe name."""
    doc = json.loads(data.decode("utf-8"))
    dive = doc.get("dive") if isinstance(doc, dict) else None
    return safe_dive(str(dive)) if dive else None


def index_topics(data: bytes) -> list[Topic] | None:
    """The topics an index.json lists (top-level ``topics``: name, positive, negatives), else None (an older
    companion, which follows one query and says nothing of it)."""
    doc = json.loads(data.decode("utf-8"))
    items = doc.get("topics") if isinstance(doc, dict) else None
    if not isinstance(items, list):
        return None
    if len(items) > MAX_TOPICS:  # what the companion's own queries parser allows (vehicle/protocol/queries.py)
        raise ValueError(f"index lists {len(items)} topics, more than {MAX_TOPICS}")
    topics = []
    for item in items:
        if isinstance(item, dict) and isinstance(item.get("name"), str) and item["name"]:
            negatives = item.get("negatives") if isinstance(item.get("negatives"), list) else []
            topic = Topic(item["name"], str(item.get("positive") or ""), tuple(str(n) for n in negatives))
            if not NAME.fullmatch(topic.name) or len(topic.negatives) > MAX_NEGATIVES or any(
                    len(text) > MAX_LINE for text in (topic.positive, *topic.negatives)):
                raise ValueError(f"index topic {topic.name[:30]!r}: not a topic the companion could follow")
            topics.append(topic)
    return topics


def parse_index(data: bytes) -> list[Capture]:
    """/summary/index.json -> the captures now in the summary (with score, heading, depth, time where given)."""
    doc = json.loads(data.decode("utf-8"))
    items = doc
    dive = doc.get("dive") if isinstance(doc, dict) else None
    if isinstance(doc, dict):
        items = _first(doc, "frames", "summary", "captures", "images", "items") or []
    if isinstance(items, (list, dict)) and len(items) > MAX_SUMMARY:
        raise ValueError(f"index lists {len(items)} frames, more than {MAX_SUMMARY}")
    if isinstance(items, dict):
        items = [dict(v, image_index=v.get("image_index", k)) for k, v in items.items()]
    out = []
    for item in items:
        if not isinstance(item, dict):
            continue
        index = _first(item, "image_index", "index", "idx", "n")
        if index is None:
            continue
        pose = item.get("pose") if isinstance(item.get("pose"), dict) else {}
        tags = {**pose, **{k: v for k, v in item.items() if k != "pose"}}
        depth = _num(_first(tags, "depth_m", "depth"))
        if depth is None and _num(tags.get("relative_alt")) is not None:
            depth = -_num(tags["relative_alt"]) / 1000.0
        q = _first(tags, "q")
        heading = _num(_first(tags, "heading_deg", "heading"))
        heading = None if heading is None else compass(heading)
        if heading is None and isinstance(q, list):
            heading = heading_from_q([float(v) for v in q])
        url = _first(tags, "file_url", "thumbnail", "thumb", "url", "file", "path")
        if isinstance(url, str) and not url.startswith("mftp://"):
            url = "mftp://" + url.lstrip("/") if "/" in url else f"mftp://summary/{url}"
        size = _first(tags, "thumbnail_bytes", "thumb_bytes", "bytes")
        cap = Capture(
            image_index=int(index),
            dive=safe_dive(str(dive)) if dive else dive_of(url if isinstance(url, str) else None),
            time_utc=_epoch_s(_first(tags, "time_utc", "capture_time", "time", "timestamp")),
            depth_m=depth, heading_deg=heading,
            q=[float(v) for v in q] if isinstance(q, list) and len(q) == 4 else None,
            lat=_num(tags.get("lat")), lon=_num(tags.get("lon")), alt_m=_num(tags.get("alt_m")),
            score=_num(_first(tags, "score", "ss", "semantic_score")),
            raw_score=_num(tags.get("raw_score")),
            topic=tags["topic"] if isinstance(tags.get("topic"), str) and NAME.fullmatch(tags["topic"]) else None,
            below_threshold=tags["below_threshold"] if isinstance(tags.get("below_threshold"), bool) else None,
            file_url=url if isinstance(url, str) and len(url) <= MAX_URL else None,
        )
        cap.thumbnail_bytes = int(size) if _num(size) is not None else None
        crc = _num(_first(tags, "thumbnail_crc32", "crc32"))
        cap.thumbnail_crc32 = int(crc) & 0xFFFFFFFF if crc is not None else None
        out.append(cap)
    return out
