"""VIAME/DIVE CSV: the header DIVE writes and reads, one whole-frame detection per summary frame.

Columns, as DIVE documents them: track id, image name, frame number, box (top-left x, y, bottom-right x, y),
confidence, target length (-1: none), then species-confidence pairs, then ``(atr) NAME VALUE`` attributes. A
summary frame is one track (its own id), its box the whole frame, its species the query with the frame's score;
depth, altitude, heading, attitude, position (when valid), the capture times and the dive are attributes (DIVE
types numbers as numbers). Frame numbers count the images in the order written, which is how DIVE pairs rows
with an image sequence.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from companion.export.paths import relative_url
from companion.export.records import FrameRecord

HEADER = ["# 1: Detection or Track-id", "2: Video or Image Identifier", "3: Unique Frame Identifier",
          "4-7: Img-bbox(TL_x", "TL_y", "BR_x", "BR_y)", "8: Detection or Length Confidence",
          "9: Target Length (0 or -1 if invalid)", "10-11+: Repeated Species", "Confidence Pairs or Attributes"]
ATTRIBUTES = ("dive", "frame", "source", "capture_utc", "autopilot_utc", "time_boot_ms", "depth_m", "altitude_m",
              "heading_deg", "roll_deg", "pitch_deg", "yaw_deg", "lat", "lon", "topic")


def _species(record: FrameRecord) -> str:
    """The query as a species name; DIVE splits rows on commas (csv quotes them) and reads '(' as an attribute."""
    name = (record.query or record.topic or "summary").strip()
    return name.lstrip("(") or "summary"


DECIMALS = {"lat": 7, "lon": 7, "depth_m": 3, "altitude_m": 3, "heading_deg": 2, "roll_deg": 2, "pitch_deg": 2,
            "yaw_deg": 2}
"""Fixed decimals, never exponents: 7 for lat/lon (~1 cm; ``.7g`` cut 151.2152967 to 151.2153, ~5 m), mm for
depth and altitude, 0.01 degree for angles (``.7g`` wrote a heading of 0 as 4.720046e-10)."""


def _value(key: str, value: object) -> str:
    if isinstance(value, float):
        text = f"{value:.{DECIMALS.get(key, 6)}f}"
        return "0" + text[2:] if text.startswith("-0") and not text.strip("-0.") else text  # no "-0.00"
    return str(value).replace(" ", "_")  # DIVE's attribute value is the rest of the cell; keep it one word


def render(records: list[FrameRecord], out: Path) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(HEADER)
    for n, r in enumerate(records):
        row: list[object] = [n, relative_url(r.image, out), n, 0, 0, r.width, r.height, f"{r.score:.6f}", -1,
                             _species(r), f"{r.score:.6f}"]
        row += [f"(atr) {key} {_value(key, getattr(r, key))}" for key in ATTRIBUTES
                if getattr(r, key) is not None and getattr(r, key) != ""]
        writer.writerow(row)
    return buf.getvalue()
