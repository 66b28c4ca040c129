"""``export(source, format, out)``: read the frames, render the chosen format, write it atomically."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.errors import UsageError
from companion.export import coco, fathomnet, viame_csv
from companion.export.records import FrameRecord, campaign_records, read_records

FORMATS: dict[str, Callable[[list[FrameRecord], Path], str]] = {
    "fathomnet": fathomnet.render,
    "coco": coco.render,
    "csv": viame_csv.render,
}
SUFFIX = {"fathomnet": ".json", "coco": ".json", "csv": ".csv"}
PROTECTED = {"summary.json", "tags.json", "manifest.json", "changes.jsonl", "params.json", "queries.json",
             "marks.json", "scores.csv", "next_index", "lock"}
"""Files a store or summary folder is made of: an export never overwrites one."""


def check_out(out: Path) -> None:
    if out.is_dir():
        raise UsageError(f"--out {out}: is a folder; name the file to write")
    if out.name in PROTECTED or out.suffix.lower() in {".jpg", ".jpeg", ".npy"}:
        raise UsageError(f"--out {out}: would overwrite a file of a store or summary; choose another name")
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: folder {out.parent} does not exist")


def export(source: str | Path, fmt: str, out: str | Path) -> list[FrameRecord]:
    """Write the frames at ``source`` to ``out`` in ``fmt``; returns the records written."""
    if fmt not in FORMATS:
        raise UsageError(f"--format {fmt}: not one of {', '.join(FORMATS)}")
    out = Path(out)
    check_out(out)
    records = read_records(source)
    atomic_write(out, FORMATS[fmt](records, out))
    return records


CAMPAIGN_FILES = {"fathomnet": "export_fathomnet.json", "coco": "export_coco.json", "csv": "export_viame.csv"}
"""What the archive writes beside its report, one file per format over all its dives."""


def write_campaign_exports(out_dir: Path, names: list[str]) -> dict[str, Path]:
    """Every format over the dives ``names`` of the campaign at ``out_dir``; returns the files by format."""
    records = campaign_records(out_dir, names)
    written = {}
    for fmt, name in CAMPAIGN_FILES.items():
        path = out_dir / name
        atomic_write(path, FORMATS[fmt](records, path))
        written[fmt] = path
    return written
