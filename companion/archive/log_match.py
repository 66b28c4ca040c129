"""Which dive log covers which dive, and when each dive started on the log's clock.

By file times: each log's span (first and last record) is read in one streaming pass, and a dive goes to the log
whose span overlaps the dive's span the most. By mapping file: a CSV with the header ``video,tlog,offset_s`` says
that ``video`` (a file name or path) started ``offset_s`` seconds after the first record of ``tlog`` (a path,
relative to the mapping file), for copies whose file times no longer mean anything.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from companion.archive.dives import Dive
from companion.archive.tlog_stream import log_span
from companion.errors import MerlionError, UsageError

LOG_SUFFIXES = (".tlog",)


@dataclass(frozen=True)
class LogMatch:
    dive: Dive
    """The dive, its ``start_time`` set from the mapping when one was given."""
    tlog: Path | None
    """The log that covers it; None when no log does."""


def find_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Every .tlog named by ``paths`` (files, or folders searched recursively)."""
    logs: list[Path] = []
    for raw in paths:
        p = Path(raw).expanduser().resolve()
        if p.is_dir():
            logs.extend(sorted(q for q in p.rglob("*") if q.is_file() and q.suffix.lower() in LOG_SUFFIXES))
        elif p.is_file():
            logs.append(p)
        else:
            raise UsageError(f"{raw}: no such telemetry log or folder")
    return list(dict.fromkeys(logs))


@dataclass(frozen=True)
class MappingRow:
    tlog: Path
    offset_s: float


def read_mapping(path: str | Path) -> dict[str, MappingRow]:
    """``video -> (tlog, offset)`` from the mapping CSV; MerlionError naming the file, line and value."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise MerlionError(f"{p}: cannot read the mapping file ({err.strerror or err})") from None
    rows = csv.DictReader(text.splitlines())
    if rows.fieldnames is None or not {"video", "tlog", "offset_s"} <= set(rows.fieldnames):
        raise MerlionError(f"{p}: the mapping file needs the header video,tlog,offset_s")
    out: dict[str, MappingRow] = {}
    for line, row in enumerate(rows, start=2):
        try:
            offset = float(row["offset_s"])
        except (TypeError, ValueError):
            raise MerlionError(f"{p}: line {line}: offset_s {row['offset_s']!r} is not a number") from None
        tlog = (p.parent / row["tlog"]).resolve()
        if not tlog.is_file():
            raise UsageError(f"{p}: line {line}: no such telemetry log {row['tlog']!r}")
        out[row["video"]] = MappingRow(tlog, offset)
    return out


def _mapped(dive: Dive, mapping: dict[str, MappingRow]) -> MappingRow | None:
    for key in (str(dive.source), dive.source.name):
        if key in mapping:
            return mapping[key]
    return None


def match_logs(dives: Sequence[Dive], logs: Sequence[Path], mapping: dict[str, MappingRow] | None = None,
               spans: dict[Path, tuple[float, float]] | None = None) -> list[LogMatch]:
    """Each dive with the log that covers it (mapping first, then the largest overlap of file times)."""
    mapping = mapping or {}
    spans = dict(spans or {})
    needed = {row.tlog for row in mapping.values()} | set(logs)
    for log in needed:
        if log not in spans:
            spans[log] = log_span(log)
    matches = []
    for dive in dives:
        row = _mapped(dive, mapping)
        if row is not None:
            matches.append(LogMatch(replace(dive, start_time=spans[row.tlog][0] + row.offset_s), row.tlog))
            continue
        best, best_overlap = None, 0.0
        for log in logs:
            first, last = spans[log]
            overlap = min(last, dive.end_time) - max(first, dive.start_time)
            if overlap > best_overlap or (best is None and overlap >= 0 and first <= dive.start_time <= last):
                best, best_overlap = log, max(overlap, best_overlap)
        matches.append(LogMatch(dive, best))
    return matches
