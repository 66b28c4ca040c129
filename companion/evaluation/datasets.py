"""Reading labelled frames and human summaries: the paper's JSON data sets and a plain CSV for new videos.

Everything is turned into 1-based frame numbers (the paper's numbering), so one SRUM implementation serves all.

CSV label format (a header row is required; columns in any order, extra columns ignored):

* ``frame,labels``: ``frame`` is the 1-based frame number, ``labels`` the frame's labels separated by ``;``
  (``|`` also accepted), empty for a frame with nothing of interest. Example row: ``17,Grey_fish_A;Reef_fish_A``.
* ``frame_index,...,<name>_present``: the survey style. ``frame_index`` is 0-based and becomes frame
  ``frame_index + 1``; every ``<name>_present`` column whose value is non-zero adds the label ``<name>``
  (``fish_present=1`` -> ``fish``).
* An optional ``segment`` column names the contiguous part of the video a frame belongs to (used for coverage).

Human summaries for a CSV data set come from ``--humans FILE``: a JSON object ``{"id": [frames...]}`` or a text
file with one summary per line (frame numbers separated by spaces or commas; ``#`` starts a comment).
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from companion.errors import MerlionError, UsageError

_SPLIT = re.compile(r"[;|]")


@dataclass
class LabelTable:
    """Per-frame labels of one video, keyed by 1-based frame number."""

    labels: dict[int, frozenset[str]]
    source: str
    fps: float | None = None
    segments: dict[int, str] = field(default_factory=dict)
    """1-based frame -> segment name (empty when the file has none)."""

    @property
    def num_frames(self) -> int:
        return max(self.labels) if self.labels else 0

    def species(self) -> list[str]:
        return sorted(set().union(*self.labels.values())) if self.labels else []


@dataclass
class SrumDataset:
    """One of the paper's data sets: labels, human summaries, stored automatic summaries and Table I values."""

    name: str
    condition: str
    table: LabelTable
    humans: dict[str, list[int]]
    paper_human_ids: list[str]
    automatic: dict[str, list[int]]
    columns: dict[str, dict]
    paper_table: dict[str, float | None]
    raw_excluded: dict[str, list[int]] = field(default_factory=dict)
    """Human summaries the released script defined but left out of its list (Table I may still need them)."""

    def paper_humans(self) -> dict[str, list[int]]:
        """The human set that reproduces Table I (all 16 for Clear, which the released script's list lacks)."""
        pool = {**self.humans, **self.raw_excluded}
        return {hid: pool[hid] for hid in self.paper_human_ids}


def _frames(values: object, where: str) -> list[int]:
    if not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        raise MerlionError(f"{where}: must be a list of integer frame numbers")
    return list(values)


def load_dataset(path: str | Path) -> SrumDataset:
    """A data set JSON as in ../shared/data/srum/ (see its README.md for the layout)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise MerlionError(f"{p}: not a readable JSON data set ({err})") from None
    if not isinstance(data, dict):
        raise MerlionError(f"{p}: top level must be an object")
    for key in ("frame_labels", "human_summaries"):
        if key not in data:
            raise MerlionError(f"{p}: missing key {key!r}")
    for key in ("frame_labels", "human_summaries", "human_summaries_excluded", "automatic_summaries",
                "table_column_mapping", "paper_table"):
        if data.get(key) is not None and not isinstance(data[key], dict):
            raise MerlionError(f"{p}: {key} must be an object, got {type(data[key]).__name__} {data[key]!r:.40}")
    labels: dict[int, frozenset[str]] = {}
    for frame, names in data["frame_labels"].items():
        try:
            number = int(frame)
        except ValueError:
            raise MerlionError(f"{p}: frame_labels key {frame!r} is not a frame number") from None
        if isinstance(names, str) or not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise MerlionError(f"{p}: frame_labels.{frame} must be a list of label names, got {names!r:.40}")
        labels[number] = frozenset(n for n in names if n)
    humans = {k: _frames(v, f"{p}: human_summaries.{k}") for k, v in data["human_summaries"].items()}
    excluded = {k: _frames(v, f"{p}: human_summaries_excluded.{k}")
                for k, v in (data.get("human_summaries_excluded") or {}).items()}
    automatic = {k: _frames(v, f"{p}: automatic_summaries.{k}")
                 for k, v in (data.get("automatic_summaries") or {}).items()}
    fps = data.get("fps", 30)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not math.isfinite(fps) or fps <= 0:
        raise MerlionError(f"{p}: fps must be a positive number, got {fps!r:.40}")
    paper_ids = list(data.get("paper_table_human_ids") or humans)
    missing = [h for h in paper_ids if h not in humans and h not in excluded]
    if missing:
        raise MerlionError(f"{p}: paper_table_human_ids names unknown human summary {missing[0]!r}")
    return SrumDataset(
        name=str(data.get("dataset", p.stem)),
        condition=str(data.get("paper_condition", "")),
        table=LabelTable(labels=labels, source=str(p), fps=float(fps)),
        humans=humans,
        paper_human_ids=paper_ids,
        automatic=automatic,
        columns=dict(data.get("table_column_mapping") or {}),
        paper_table=dict(data.get("paper_table") or {}),
        raw_excluded=excluded,
    )


_ABSENT = ("", "0", "0.0")
_PRESENT = ("1", "1.0")
"""What a ``<name>_present`` cell may hold (empty: absent)."""


def csv_rows(path: Path, *, missing: str = "no such file") -> list[dict[str, str]]:
    """A CSV file's rows under its header, or a one-line MerlionError naming the file (``missing`` says what an
    absent file means to the caller)."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))
    except FileNotFoundError:
        raise UsageError(f"{path}: {missing}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise MerlionError(f"{path}: cannot read as CSV ({err})") from None


def load_label_csv(path: str | Path, fps: float | None = None) -> LabelTable:
    """A per-frame label CSV in one of the two documented layouts (module docstring)."""
    p = Path(path)
    rows = csv_rows(p)
    if not rows:
        raise MerlionError(f"{p}: no rows (a header and one row per frame are needed)")
    cols = [c.strip() for c in rows[0]]
    present = [c for c in cols if c.endswith("_present")]
    if "frame" in cols and "labels" in cols:
        key, offset = "frame", 0
    elif "frame_index" in cols and present:
        key, offset = "frame_index", 1
    else:
        raise MerlionError(f"{p}: needs columns 'frame,labels' or 'frame_index' plus '<name>_present' (got {cols})")
    table = LabelTable(labels={}, source=str(p), fps=fps)
    for line, row in enumerate(rows, start=2):
        if None in row:  # csv.DictReader files fields past the header under None, as a list
            raise MerlionError(f"{p}: line {line}: {len(cols) + len(row[None])} fields, the header names {len(cols)}")
        row = {(k or "").strip(): (v or "").strip() for k, v in row.items()}
        try:
            frame = int(row[key]) + offset
        except ValueError:
            raise MerlionError(f"{p}: line {line}: {key} {row[key]!r} is not an integer") from None
        if frame < 1:
            raise MerlionError(f"{p}: line {line}: {key} {row[key]} ({'1' if offset == 0 else '0'}-based: "
                               f"must be {1 - offset} or more)")
        if frame in table.labels:
            raise MerlionError(f"{p}: line {line}: {key} {row[key]} appears twice")
        if key == "frame":
            names = frozenset(n.strip() for n in _SPLIT.split(row["labels"]) if n.strip())
        else:
            for c in present:
                if row.get(c, "") not in _ABSENT + _PRESENT:  # "no", "2", "maybe": a typo, not a fish
                    raise MerlionError(f"{p}: line {line}: {c} {row[c]!r} is not 0 or 1")
            names = frozenset(c[: -len("_present")] for c in present if row.get(c, "") in _PRESENT)
        table.labels[frame] = names
        if row.get("segment", "") != "":
            table.segments[frame] = row["segment"]
    return table


def load_labels(path: str | Path, fps: float | None = None) -> LabelTable:
    """Labels from either a data set JSON or a CSV, chosen by the file's suffix."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        table = load_dataset(p).table
        if fps is not None:
            table.fps = fps
        return table
    return load_label_csv(p, fps)


def load_humans(path: str | Path) -> dict[str, list[int]]:
    """Human summaries from a JSON object ``{id: [frames]}`` or a text file with one summary per line."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"{p}: no such file") from None
    except OSError as err:
        raise MerlionError(f"{p}: cannot read ({err.strerror})") from None
    except UnicodeDecodeError as err:
        raise MerlionError(f"{p}: not a text file (byte {err.start} is not UTF-8)") from None
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise MerlionError(f"{p}: not valid JSON ({err.msg}, line {err.lineno})") from None
        if isinstance(data, dict) and "human_summaries" in data:
            data = data["human_summaries"]
        if not isinstance(data, dict):
            raise MerlionError(f"{p}: must be an object {{id: [frames]}}")
        return {str(k): _frames(v, f"{p}: {k}") for k, v in data.items()}
    humans: dict[str, list[int]] = {}
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            humans[f"h{len(humans) + 1}"] = [int(v) for v in re.split(r"[,\s]+", line) if v]
        except ValueError:
            raise MerlionError(f"{p}: line {n}: frame numbers must be integers") from None
    if not humans:
        raise MerlionError(f"{p}: no human summaries in it")
    return humans


def read_summary_json(path: str | Path, label_fps: float | None = None) -> tuple[list[int], dict]:
    """1-based label frames of a ``merlion summarize`` summary.json, and the file's content.

    Each entry's ``index`` is the 0-based frame of the source video *before* subsampling (companion.sources.frame), so
    a summary taken at 5 fps from a 30 fps video still names source frames: label frame = index + 1. When the
    label file was made at another frame rate than the video (``label_fps``), the entry's ``time_s`` is used
    instead: label frame = round(time_s x label_fps) + 1. The on-board store's summary.json (companion.storage.store)
    is read the same way: its entries name the source frame ``frame_index`` and carry the pose tags.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "summary.json"
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{p}: no such summary file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise MerlionError(f"{p}: not a readable summary.json ({err})") from None
    entries = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        raise MerlionError(f"{p}: missing the 'frames' list")
    frames = []
    for n, entry in enumerate(entries):
        try:
            if label_fps is not None:
                frames.append(round(float(entry["time_s"]) * label_fps) + 1)
            else:
                frames.append(int(entry["index"] if "index" in entry else entry["frame_index"]) + 1)
        except (KeyError, TypeError, ValueError):
            need = "time_s" if label_fps is not None else "index"
            raise MerlionError(f"{p}: frames[{n}] has no usable {need!r}") from None
    return frames, data
