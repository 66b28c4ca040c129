"""Scoring a summary of our own labelled video (e.g. the survey clip): precision, coverage, SRUM vs an oracle.

Definitions (frames are 1-based, as in datasets.py):

* **positive frame**: a frame whose labels contain the query label (``fish``); with no query label, any frame
  with at least one label.
* **precision**: the share of summary frames that are positive.
* **segments**: the label file's ``segment`` column when it has one, else the runs of consecutive positive
  frames. A *positive segment* holds at least one positive frame.
* **coverage**: the share of positive segments holding at least one positive summary frame.
* **label coverage**: the share of all labels (species) in the file seen in at least one summary frame.
* **oracle summary** (K frames, K = the summary's size unless given): the picks are dealt one at a time to the
  positive segments, longest first, round-robin; a segment dealt n picks gets the centres of n equal slices of
  its positive frames. It is what a careful person would pick when every positive segment matters equally.
* **SRUM vs oracle**: SRUM with the oracle as the one human summary, at the label file's frame rate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

from companion.errors import MerlionError
from companion.evaluation.datasets import LabelTable
from companion.evaluation.srum import SrumParams, score


@dataclass(frozen=True)
class LabelScores:
    frames: list[int]
    precision: float
    coverage: float
    label_coverage: float
    srum_oracle: float
    oracle: list[int]
    positive_segments: int
    query: str | None

    def as_dict(self) -> dict:
        return asdict(self)


def is_positive(table: LabelTable, frame: int, query: str | None) -> bool:
    names = table.labels.get(frame, frozenset())
    return query in names if query else bool(names)


def positive_segments(table: LabelTable, query: str | None) -> list[list[int]]:
    """Positive frames grouped by segment (named segments, else consecutive runs), in video order."""
    frames = sorted(f for f in table.labels if is_positive(table, f, query))
    groups: dict[str, list[int]] = {}
    if table.segments:
        for f in frames:
            groups.setdefault(table.segments.get(f, ""), []).append(f)
        return sorted(groups.values(), key=lambda g: g[0])
    runs: list[list[int]] = []
    for f in frames:
        if runs and f == runs[-1][-1] + 1:
            runs[-1].append(f)
        else:
            runs.append([f])
    return runs


def oracle_summary(table: LabelTable, k: int, query: str | None) -> list[int]:
    """K frames dealt round-robin over positive segments (longest first), centred in each (module docstring)."""
    segs = positive_segments(table, query)
    if not segs:
        raise MerlionError(f"{table.source}: no frame is labelled {query or 'with anything'}; no oracle summary")
    order = sorted(range(len(segs)), key=lambda i: (-len(segs[i]), i))
    dealt = [0] * len(segs)
    for n in range(k):
        dealt[order[n % len(segs)]] += 1
    picks = []
    for seg, n in zip(segs, dealt, strict=True):
        n = min(n, len(seg))
        picks += [seg[int((j + 0.5) * len(seg) / n)] for j in range(n)]
    return sorted(picks)


def default_query(table: LabelTable) -> str | None:
    """``fish`` when the file has that label (the survey layout), else any label counts."""
    return "fish" if "fish" in table.species() else None


def evaluate_labels(
    table: LabelTable,
    frames: Sequence[int],
    query: str | None = None,
    k: int | None = None,
    params: SrumParams | None = None,
) -> LabelScores:
    """Precision, coverage, label coverage and SRUM against the oracle for one summary (1-based frames)."""
    if not frames:
        raise MerlionError("the summary is empty: nothing to evaluate")
    unknown = [f for f in frames if f not in table.labels]
    if unknown:
        raise MerlionError(f"summary frame {unknown[0]}: not in {table.source} (frames are 1-based)")
    if query is not None and query not in table.species():
        raise MerlionError(f"query label {query!r}: not in {table.source} (labels: {', '.join(table.species())})")
    params = params or SrumParams(fps=table.fps or 30.0)
    pos = [f for f in frames if is_positive(table, f, query)]
    segs = positive_segments(table, query)
    covered = sum(1 for seg in segs if set(seg) & set(pos))
    all_labels = table.species()
    seen = set().union(*(table.labels[f] for f in frames))
    oracle = oracle_summary(table, k or len(frames), query)
    if query:
        # SRUM matches on shared labels; restrict to the query so other labels cannot earn credit.
        only = {f: (names & {query}) for f, names in table.labels.items()}
        srum_value = score(list(frames), oracle, only, params)
    else:
        srum_value = score(list(frames), oracle, table.labels, params)
    return LabelScores(
        frames=list(frames),
        precision=len(pos) / len(frames),
        coverage=covered / len(segs),
        label_coverage=len(seen & set(all_labels)) / len(all_labels) if all_labels else 0.0,
        srum_oracle=srum_value,
        oracle=oracle,
        positive_segments=len(segs),
        query=query,
    )
