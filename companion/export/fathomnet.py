"""FathomNet image records: a JSON list of objects with the field names of fathomnet-py's ``Image`` (dto.py).

``url`` is the image's path relative to the export file (FathomNet takes the URL where the image will be served;
replace the prefix when uploading), ``sha256`` its digest, ``timestamp`` the autopilot's UTC where it has one
(else the companion's), ``depthMeters``, ``latitude``/``longitude`` only when valid. FathomNet's ``altitude`` is
height above the seabed, which the companion does not measure: the autopilot's altitude above sea level goes
in a tag instead, with heading, roll, pitch, yaw, the query, the score and both clocks.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from companion.export.paths import relative_url
from companion.export.records import FrameRecord


def _tag(key: str, value: Any) -> dict[str, str]:
    return {"key": key, "value": value if isinstance(value, str) else json.dumps(value)}


def image_record(record: FrameRecord, url: str, imaging_type: str | None = None) -> dict[str, Any]:
    """One FathomNet ``Image`` as a JSON object (fields that are not known are left out, as FathomNet does)."""
    tags = [_tag("dive", record.dive), _tag("frame", record.frame), _tag("query", record.query),
            _tag("topic", record.topic), _tag("score", round(record.score, 6))]
    if record.source is not None:
        tags.insert(2, _tag("source", record.source))
    for key in ("heading_deg", "roll_deg", "pitch_deg", "yaw_deg", "altitude_m", "capture_utc", "autopilot_utc",
                "time_boot_ms", "time_s"):
        value = getattr(record, key)
        if value is not None:
            tags.append(_tag("altitude_amsl_m" if key == "altitude_m" else key,
                             round(value, 6) if isinstance(value, float) else value))
    doc: dict[str, Any] = {
        "url": url, "imagingType": imaging_type, "mediaType": "image/jpeg" if url.lower().endswith((".jpg", ".jpeg"))
        else None, "width": record.width, "height": record.height, "depthMeters": record.depth_m,
        "latitude": record.lat, "longitude": record.lon, "timestamp": record.best_utc,
        "sha256": hashlib.sha256(record.image.read_bytes()).hexdigest(), "tags": tags,
    }
    return {k: v for k, v in doc.items() if v is not None}


def render(records: list[FrameRecord], out: Path, imaging_type: str | None = None) -> str:
    return json.dumps([image_record(r, relative_url(r.image, out), imaging_type) for r in records], indent=1) + "\n"
