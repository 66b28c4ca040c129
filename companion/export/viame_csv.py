"""VIAME/DIVE CSV: the header DIVE writes and reads, one whole-frame detection per summary frame.

Columns, as DIVE documents them: track id, image name, frame number, box (top-left x, y, bottom-right x, y),
confidence, target length (-1: none), then species-confidence pairs, then ``(atr) NAME VALUE`` attributes. A
summary frame is one track (its own id), its box the whole frame, its species the query with the frame's score;
depth, altitude, heading, attitude, position (when valid), water temperature and pressure, the capture times, the
source video and the time into it, the threshold and whether the frame is below it, and the dive are attributes
(DIVE types numbers as numbers).

DIVE pairs a row with an image by the image's name without folder or extension (Kitware/dive
server/dive_utils/serializers/viame.py, ``load_csv_as_tracks_and_attributes``: ``imageMap`` maps each image name
of the dataset to its position), and a dataset made from a folder holds every image in it, in name order. So the
CSV comes with its own image folder, ``<name>_images/`` beside it (``IMAGE_DIR``), holding exactly the exported
frames (copied, never linked), named ``000000.jpg``, ``000001.jpg``, ... in the order written: row n names image n
and frame n, whatever the store's frames folder holds besides (raw copies, frames no longer in the summary).

A cell a spreadsheet would run as a formula (one starting with ``=``, ``+``, ``-``, ``@``, also after blanks or
quotes, or with a tab or a line break, and not a plain number) gets a leading apostrophe: a query uploaded by anyone
on the link can be a formula.
"""

from __future__ import annotations

import csv
import io
import os
import re
import shutil
import tempfile
from pathlib import Path

from companion.errors import UsageError
from companion.export.records import FrameRecord

_OURS = re.compile(r"\d{6,}\.(jpg|jpeg|png)")
"""The names ``image_name`` gives: the only files a folder may hold for an export to replace it."""

HEADER = ["# 1: Detection or Track-id", "2: Video or Image Identifier", "3: Unique Frame Identifier",
          "4-7: Img-bbox(TL_x", "TL_y", "BR_x", "BR_y)", "8: Detection or Length Confidence",
          "9: Target Length (0 or -1 if invalid)", "10-11+: Repeated Species", "Confidence Pairs or Attributes"]
ATTRIBUTES = ("dive", "frame", "source", "video", "time_s", "capture_utc", "autopilot_utc", "time_boot_ms",
              "date_source", "depth_m", "altitude_m", "heading_deg", "roll_deg", "pitch_deg", "yaw_deg", "lat", "lon",
              "water_temp_c", "pressure_dbar", "topic", "threshold", "below_threshold", "pilot")
FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "\n", "\uff1d", "\uff0b", "\uff0d", "\uff20")
"""A formula's first characters, with their full-width forms (an East Asian spreadsheet may read them alike)."""
_LEADING = " \t\r\n\f\v\u00a0\u3000\"\u201c\u201d\u2018\u2019\ufeff"
"""What a spreadsheet may drop before reading a cell's first character: blanks, double quotes, a byte-order mark
(not the apostrophe: that is the escape itself)."""
_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")
"""A plain number as the exports write one (``float()`` also takes ``" -1"``, ``"-1_0"`` and ``"-inf"``)."""


def image_dir(out: Path) -> Path:
    """The image folder that goes with the CSV ``out``: ``<stem>_images`` beside it."""
    return out.with_name(f"{out.stem}_images")


def image_name(n: int, record: FrameRecord) -> str:
    """Row n's image, as DIVE's dataset from ``image_dir`` holds it (names sort in the order written)."""
    return f"{n:06d}{record.image.suffix.lower() or '.jpg'}"


def sheet_safe(cell: str) -> str:
    """A cell no spreadsheet runs: a leading apostrophe when it starts a formula, also past blanks and quotes (a
    spreadsheet that trims them on import, LibreOffice's "Trim spaces", reads ``  =1+1`` as a formula); plain
    numbers as they are."""
    if _NUMBER.fullmatch(cell):
        return cell
    if cell.startswith(FORMULA_START) or cell.lstrip(_LEADING).startswith(FORMULA_START):
        return "'" + cell
    return cell


def _species(record: FrameRecord) -> str:
    """The query as a species name; DIVE splits rows on commas (csv quotes them) and reads '(' as an attribute."""
    name = (record.query or record.topic or "summary").strip()
    return name.lstrip("(") or "summary"


DECIMALS = {"lat": 7, "lon": 7, "depth_m": 3, "altitude_m": 3, "heading_deg": 2, "roll_deg": 2, "pitch_deg": 2,
            "yaw_deg": 2, "time_s": 3, "water_temp_c": 2, "pressure_dbar": 3, "threshold": 4}
"""Fixed decimals, never exponents: 7 for lat/lon (~1 cm; ``.7g`` cut 151.2152967 to 151.2153, ~5 m), mm for
depth and altitude, 0.01 degree for angles (``.7g`` wrote a heading of 0 as 4.720046e-10)."""


def _value(key: str, value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"  # DIVE's own spelling of a boolean attribute
    if isinstance(value, float):
        text = f"{value:.{DECIMALS.get(key, 6)}f}"
        return "0" + text[2:] if text.startswith("-0") and not text.strip("-0.") else text  # no "-0.00"
    return str(value).replace(" ", "_")  # DIVE's attribute value is the rest of the cell; keep it one word


def render(records: list[FrameRecord], out: Path) -> str:
    """The CSV; its rows name the images ``copy_images`` puts in ``image_dir(out)``."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(HEADER)
    folder = image_dir(out).name
    for n, r in enumerate(records):
        row: list[object] = [n, f"{folder}/{image_name(n, r)}", n, 0, 0, r.width, r.height, f"{r.score:.6f}", -1,
                             _species(r), f"{r.score:.6f}"]
        row += [f"(atr) {key} {_value(key, getattr(r, key))}" for key in ATTRIBUTES
                if getattr(r, key) is not None and getattr(r, key) != ""]
        writer.writerow([sheet_safe(str(cell)) for cell in row])
    return buf.getvalue()


def _copy_no_link(src: Path, dst: Path) -> None:
    """``src``'s bytes to a new ``dst``, opened with ``O_NOFOLLOW``: a frame swapped for a link after it was
    checked is refused (``copyfile(follow_symlinks=False)`` copied the link itself into the export)."""
    try:
        fd = os.open(src, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError as err:
        raise UsageError(f"{src}: not copied ({err.strerror}); an export follows no link") from None
    with os.fdopen(fd, "rb") as fh, dst.open("xb") as out:
        shutil.copyfileobj(fh, out)


def copy_images(records: list[FrameRecord], out: Path) -> Path:
    """``image_dir(out)`` with exactly the rows' images, replaced whole (built aside, then swapped in); a folder
    there that holds anything else is left alone and refused."""
    target = image_dir(out)
    if target.is_symlink() or (target.exists() and (not target.is_dir() or any(
            not p.is_file() or not _OURS.fullmatch(p.name) for p in target.iterdir()))):
        raise UsageError(f"{target}: exists and is not an image folder an export wrote; move it aside")
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=out.parent))
    try:
        for n, r in enumerate(records):
            _copy_no_link(r.image, staging / image_name(n, r))
        if target.exists():
            shutil.rmtree(target)
        staging.rename(target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return target
