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


def _write(records: list[FrameRecord], fmt: str, out: Path, base_url: str | None = None) -> None:
    """One format to ``out``; the CSV's image folder first (``viame_csv.copy_images``: the rows name its images)."""
    if fmt == "csv":
        viame_csv.copy_images(records, out)
    text = fathomnet.render(records, out, base_url) if fmt == "fathomnet" else FORMATS[fmt](records, out)
    atomic_write(out, text)


def check_base_url(base_url: str | None) -> None:
    if base_url is not None and not base_url.startswith(("http://", "https://")):
        raise UsageError(f"--base-url {base_url}: not an http:// or https:// URL")


def export(source: str | Path, fmt: str, out: str | Path, base_url: str | None = None) -> list[FrameRecord]:
    """Write the frames at ``source`` to ``out`` in ``fmt`` (FathomNet URLs under ``base_url`` when given);
    returns the records written."""
    if fmt not in FORMATS:
        raise UsageError(f"--format {fmt}: not one of {', '.join(FORMATS)}")
    check_base_url(base_url)
    out = Path(out)
    check_out(out)
    records = read_records(source)
    _write(records, fmt, out, base_url)
    return records


CAMPAIGN_FILES = {"fathomnet": "export_fathomnet.json", "coco": "export_coco.json", "csv": "export_viame.csv"}
"""What the archive writes beside its report, one file per format over all its dives."""


def write_campaign_exports(out_dir: Path, names: list[str]) -> dict[str, Path]:
    """Every format over the dives ``names`` of the campaign at ``out_dir``; returns the files by format."""
    records = campaign_records(out_dir, names)
    written = {}
    for fmt, name in CAMPAIGN_FILES.items():
        path = out_dir / name
        _write(records, fmt, path)
        written[fmt] = path
    return written
