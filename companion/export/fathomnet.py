"""FathomNet image records: a JSON list of objects with the field names of fathomnet-py's ``Image`` (dto.py).

``url`` is where FathomNet will fetch the image: ``--base-url`` plus the image's path under the folder holding
every exported image (serve that folder there), else the image's absolute ``file://`` URL, to be replaced before
uploading (docs/archive.md). ``imagingType`` is ``ROV`` (the vehicle is one), ``sha256`` the image's digest,
``timestamp`` the best clock the frame has (``FrameRecord.best_utc``, named in the tag ``date_source``),
``depthMeters``, ``latitude``/``longitude`` only when valid, ``temperatureCelsius`` and ``pressureDbar`` where the
vehicle's external pressure sensor gave them. A frame that matched its query gets one whole-frame bounding box per
concept the query names (the nouns the query resolves to, ``encoders.query_words``: "underwater image with fish"
-> ``fish``); a frame below the threshold gets none (it is not a sighting) and says so in its tags, with the
threshold. FathomNet's ``altitude`` is height above the seabed, which the companion does not measure: the
autopilot's altitude above sea level goes in a tag instead, with heading, roll, pitch, yaw, the query, the score
and the clocks.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from companion.errors import MerlionError
from companion.export.paths import absolute_url, image_root
from companion.export.records import FrameRecord, image_bytes
from companion.vision.encoders.query_cache import resolve_cached

log = logging.getLogger(__name__)

IMAGING_TYPE = "ROV"
"""FathomNet's imaging type for images from a remotely operated vehicle (a BlueROV2)."""
TAG_KEYS = ("heading_deg", "roll_deg", "pitch_deg", "yaw_deg", "altitude_m", "capture_utc", "autopilot_utc",
            "time_boot_ms", "time_s", "video", "threshold", "date_source")


def _tag(key: str, value: Any) -> dict[str, str]:
    return {"key": key, "value": value if isinstance(value, str) else json.dumps(value)}


@functools.lru_cache(maxsize=64)
def concepts_of(query: str) -> tuple[str, ...]:
    """The concepts a query names: the nouns of its terms that say what is seen (not where), in order; none for a
    negated query ("no fish") or one the resolver cannot read (then the tag ``query`` is all there is)."""
    if not query.strip():
        return ()
    try:
        resolved = resolve_cached(query)
    except (MerlionError, OSError, ValueError) as err:
        log.info("query %r names no concept for FathomNet: %s", query, err)
        return ()
    if resolved.negated:
        return ()
    return tuple(dict.fromkeys(t.noun for t in resolved.terms if not t.context))


def image_record(record: FrameRecord, url: str, imaging_type: str | None = IMAGING_TYPE) -> dict[str, Any]:
    """One FathomNet ``Image`` as a JSON object (fields that are not known are left out, as FathomNet does)."""
    tags = [_tag("dive", record.dive), _tag("frame", record.frame), _tag("query", record.query),
            _tag("topic", record.topic), _tag("score", round(record.score, 6)),
            _tag("below_threshold", record.below_threshold), _tag("pilot", record.pilot)]
    if record.source is not None:
        tags.insert(2, _tag("source", record.source))
    for key in TAG_KEYS:
        value = getattr(record, key)
        if value is not None:
            tags.append(_tag("altitude_amsl_m" if key == "altitude_m" else key,
                             round(value, 6) if isinstance(value, float) else value))
    boxes = [] if record.below_threshold else [
        {"concept": concept, "x": 0, "y": 0, "width": record.width, "height": record.height}
        for concept in concepts_of(record.query)]
    doc: dict[str, Any] = {
        "url": url, "imagingType": imaging_type,
        "mediaType": "image/jpeg" if record.image.suffix.lower() in (".jpg", ".jpeg") else None,
        "width": record.width, "height": record.height, "depthMeters": record.depth_m,
        "latitude": record.lat, "longitude": record.lon, "timestamp": record.best_utc,
        "temperatureCelsius": record.water_temp_c, "pressureDbar": record.pressure_dbar,
        "sha256": hashlib.sha256(image_bytes(record.image)).hexdigest(), "boundingBoxes": boxes or None,
        "tags": tags,
    }
    return {k: v for k, v in doc.items() if v is not None}


def render(records: list[FrameRecord], out: Path, base_url: str | None = None) -> str:
    root = image_root([r.image for r in records])
    return json.dumps([image_record(r, absolute_url(r.image, root, base_url)) for r in records], indent=1) + "\n"
