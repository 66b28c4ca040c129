"""The science tools' own reading of our exports, shared by the export tests and the live store's test.

- ``dive_read``: DIVE's VIAME CSV rules (Kitware/dive server/dive_utils/serializers/viame.py,
  ``load_csv_as_tracks_and_attributes`` and ``_parse_row``): comment rows skipped; track, image, frame, box,
  length; species pairs from column 10 until a cell starting with ``(``; ``(atr) name value`` attributes typed as
  DIVE types them (true/false, numbers, text); and the ``imageMap`` a dataset made from the CSV's image folder
  gives: each image's name without folder or extension -> its position in name order. A row whose image is not
  in the map, or whose frame is not that image's position, is a box on the wrong frame.
- ``coco_read``: pycocotools' ``COCO()``, and ``annToMask`` on every annotation.
- ``fathomnet_read``: fathomnet-py's ``Image.from_dict`` on every record.
"""

from __future__ import annotations

import csv
import os
import re
from pathlib import Path

FORMULA = ("=", "+", "-", "@", "\uff1d", "\uff0b", "\uff0d", "\uff20")
TRIMMED = " \t\r\n\u00a0\u3000\"\u201c\u201d\ufeff"
"""What a spreadsheet that trims cells on import may drop before the first character it reads."""


def _deduce(value: str):
    """DIVE's ``_deduceType``."""
    if value == "true":
        return True
    if value == "false":
        return False
    try:
        return float(value)
    except ValueError:
        return value


def dive_read(path: Path) -> list[dict]:
    """The rows of a VIAME CSV as DIVE reads them, each checked against the image folder's ``imageMap``."""
    rows = []
    cells = list(csv.reader(path.read_text().splitlines()))
    for row in cells:
        if not row or row[0].startswith("#"):
            continue
        pairs = [(row[i], float(row[i + 1])) for i in range(9, len(row), 2)
                 if i + 1 < len(row) and row[i] and row[i + 1] and not row[i].startswith("(")]
        attrs = {}
        for cell in row[9 + 2 * len(pairs):]:
            m = re.match(r"^\(atr\) (.*?)\s(.+)", cell)
            assert m, cell
            attrs[m[1]] = _deduce(m[2])
        rows.append({"track": int(row[0]), "image": row[1], "frame": int(row[2]),
                     "box": [round(float(x)) for x in row[3:7]], "confidence": float(row[7]),
                     "length": float(row[8]), "pairs": pairs, "attrs": attrs})
    folder = path.with_name(f"{path.stem}_images")
    names = sorted(p.name for p in folder.iterdir())
    image_map = {os.path.splitext(name)[0]: i for i, name in enumerate(names)}
    assert len(names) == len(rows), "the dataset holds exactly the exported frames"
    for r in rows:
        name = os.path.splitext(os.path.basename(r["image"]))[0]
        assert image_map.get(name) == r["frame"], f"row {r['track']}: image {r['image']} is not frame {r['frame']}"
        assert (path.parent / r["image"]).is_file()
    return rows


def formula_cells(path: Path) -> list[str]:
    """Cells a spreadsheet would run: starting with = + - @ (or their full-width forms), also past blanks and
    quotes a spreadsheet may trim, or with a tab or line break; and not a plain number."""
    found = []
    with path.open(newline="", encoding="utf-8") as fh:
        for row in csv.reader(fh):
            for cell in row:
                if cell.lstrip(TRIMMED).startswith(FORMULA) or cell.startswith(("\t", "\r", "\n")):
                    if not re.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", cell):
                        found.append(cell)
    return found


def coco_read(path: Path):
    """pycocotools' COCO of ``path``; every annotation's mask made (annToMask) and checked against its box."""
    from pycocotools.coco import COCO

    coco = COCO(str(path))
    for ann in coco.loadAnns(coco.getAnnIds()):
        img = coco.loadImgs([ann["image_id"]])[0]
        mask = coco.annToMask(ann)
        assert mask.shape == (img["height"], img["width"]) and int(mask.sum()) == ann["area"]
    return coco


def fathomnet_read(docs: list[dict]) -> list:
    from fathomnet import dto

    known = set(dto.Image.model_fields)
    for doc in docs:
        assert set(doc) <= known, set(doc) - known
    return [dto.Image.from_dict(doc) for doc in docs]
