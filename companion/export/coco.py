"""COCO: ``images``, ``annotations`` and ``categories`` as pycocotools' ``COCO()`` loads them.

A summary frame is tagged as a whole, not by boxes: each image gets one annotation covering the whole frame,
whose category is its topic (named by the topic's query) and whose ``score`` is the frame's relevance, with
``below_threshold`` and the ``threshold`` beside it (a stand-in or a pilot's frame under the threshold is not a
match of its category). The whole frame is also the annotation's ``segmentation`` (one polygon), which
pycocotools' ``annToMask``/``annToRLE`` need (pycocotools/coco.py reads ``segmentation`` unconditionally). The
image's best known time is COCO's ``date_captured`` (an offline summary: the video file's, ``date_source`` says
which); depth, altitude, heading, attitude, position (when valid), water temperature and pressure, the source
video and the frame's time into it ride along as extra keys of the image, which COCO readers keep.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from companion.export.paths import relative_url
from companion.export.records import FrameRecord

EXTRA = ("dive", "frame", "source", "video", "time_s", "capture_utc", "autopilot_utc", "time_boot_ms", "date_source",
         "depth_m", "altitude_m", "heading_deg", "roll_deg", "pitch_deg", "yaw_deg", "lat", "lon", "water_temp_c",
         "pressure_dbar", "query", "topic", "score", "threshold", "below_threshold", "pilot")


def _coco_time(iso: str | None) -> str:
    """COCO's ``date_captured`` form (``YYYY-MM-DD HH:MM:SS``, UTC here); empty when the time is unknown."""
    if not iso:
        return ""
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def document(records: list[FrameRecord], out: Path) -> dict[str, Any]:
    """The COCO document for ``records``, images numbered from 1 in the order given."""
    categories: dict[tuple[str, str], int] = {}
    for r in records:
        categories.setdefault((r.topic, r.query), len(categories) + 1)
    images, annotations = [], []
    for n, r in enumerate(records, start=1):
        extra = {k: getattr(r, k) for k in EXTRA if getattr(r, k) is not None}
        images.append({"id": n, "file_name": relative_url(r.image, out), "width": r.width, "height": r.height,
                       "date_captured": _coco_time(r.best_utc), **extra})
        w, h = r.width, r.height
        annotations.append({"id": n, "image_id": n, "category_id": categories[(r.topic, r.query)],
                            "bbox": [0, 0, w, h], "area": w * h, "iscrowd": 0,
                            "segmentation": [[0, 0, w, 0, w, h, 0, h]],
                            "score": round(r.score, 6), "threshold": r.threshold,
                            "below_threshold": r.below_threshold, "pilot": r.pilot})
    return {
        "info": {"description": "MERLION summary frames", "version": "1.0",
                 "date_created": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S")},
        "licenses": [],
        "images": images,
        "annotations": annotations,
        "categories": [{"id": i, "name": query or topic or "summary", "supercategory": topic or "summary"}
                       for (topic, query), i in categories.items()],
    }


def render(records: list[FrameRecord], out: Path) -> str:
    return json.dumps(document(records, out), indent=1) + "\n"
