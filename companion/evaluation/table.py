"""Table I of the paper, recomputed from the data sets and set beside the printed values.

The paper prints 4 decimals for Low and Clear and 3 for Moderate. Every printed value is the rounded SRUM except
one: Low MERLION-E is 0.40699..., printed 0.4069, i.e. truncated. ``compare_printed`` accepts a value when it
rounds to the printed one, and reports a truncation only where rounding fails and truncating matches, so a
second truncation would show up instead of hiding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

from companion.errors import MerlionError, UsageError
from companion.evaluation.datasets import SrumDataset, load_dataset
from companion.evaluation.srum import PAPER, SrumParams, human_score, srum

DATASET_ORDER = ("powellscay_low", "bonaire_moderate", "kralendijk_clear")
COLUMNS = ("MERLION", "MERLION-E", "ROST", "ROST-Enhanced", "Human")
TRUNCATED = {("powellscay_low", "MERLION-E")}
"""The entries the paper truncated rather than rounded (asserted by the tests, documented in docs/evaluation.md)."""


@dataclass(frozen=True)
class Cell:
    dataset: str
    column: str
    ours: float | None
    paper: float | None
    decimals: int
    verdict: str
    """"rounded" (ours rounds to the printed value), "truncated", "mismatch", or "-" (not reported)."""


def printed_decimals(value: float) -> int:
    """How many decimals the paper printed, read from the shortest repr of the stored value."""
    exp = Decimal(repr(value)).as_tuple().exponent
    return -exp if isinstance(exp, int) and exp < 0 else 0


def compare_printed(ours: float, paper: float) -> tuple[int, str]:
    """(decimals, verdict): whether ``ours`` shows as ``paper`` when rounded, else when truncated."""
    d = printed_decimals(paper)
    scale = 10**d
    if round(ours, d) == round(paper, d):
        return d, "rounded"
    if math.floor(ours * scale + 1e-9) == round(paper * scale):
        return d, "truncated"
    return d, "mismatch"


def column_value(ds: SrumDataset, column: str, params: SrumParams = PAPER) -> float | None:
    """One Table I entry: Human is the leave-one-out score; other columns average SRUM over their runs."""
    humans = ds.paper_humans()
    labels = ds.table.labels
    if column == "Human":
        return human_score(humans, labels, params)
    spec = ds.columns.get(column)
    if not spec or not spec.get("runs"):
        return None
    runs = spec["runs"]
    missing = [r for r in runs if r not in ds.automatic]
    if missing:
        raise MerlionError(f"{ds.table.source}: table_column_mapping.{column} names unknown run {missing[0]!r}")
    values = [srum(ds.automatic[r], humans, labels, params) for r in runs]
    return sum(values) / len(values)


def find_datasets(data_dir: str | Path) -> list[Path]:
    """The data set JSONs in a folder, the paper's three first in the paper's order."""
    d = Path(data_dir)
    if not d.is_dir():
        raise UsageError(f"{d}: SRUM data folder not found (pass --data DIR; the paper's data is ../shared/data/srum)")
    files = sorted(d.glob("*.json"), key=lambda f: (DATASET_ORDER.index(f.stem) if f.stem in DATASET_ORDER
                                                    else len(DATASET_ORDER), f.stem))
    if not files:
        raise MerlionError(f"{d}: no data set JSON files in it")
    return files


def compute_table(data_dir: str | Path, params: SrumParams = PAPER) -> list[Cell]:
    """Every cell of Table I for every data set in ``data_dir``, with its verdict against the paper."""
    cells = []
    for path in find_datasets(data_dir):
        ds = load_dataset(path)
        for column in COLUMNS:
            ours = column_value(ds, column, params)
            paper = ds.paper_table.get(column)
            if ours is None or paper is None:
                cells.append(Cell(ds.name, column, ours, paper, 0, "-"))
                continue
            decimals, verdict = compare_printed(ours, paper)
            cells.append(Cell(ds.name, column, ours, paper, decimals, verdict))
    return cells


def table_json(cells: list[Cell]) -> dict:
    """``{dataset: {column: value}}``, keyed by the data sets' names and the table's own column names."""
    out: dict[str, dict[str, float | None]] = {}
    for c in cells:
        out.setdefault(c.dataset, {})[c.column] = c.ours
    return out


def format_table(cells: list[Cell]) -> str:
    """A plain-text table: ours (6 decimals), the paper's printed value, and the verdict."""
    lines = [f"{'dataset':<18} {'column':<14} {'ours':>9} {'paper':>8}  verdict"]
    for c in cells:
        ours = "-" if c.ours is None else f"{c.ours:.6f}"
        paper = "-" if c.paper is None else f"{c.paper:.{c.decimals}f}"
        lines.append(f"{c.dataset:<18} {c.column:<14} {ours:>9} {paper:>8}  {c.verdict}")
    return "\n".join(lines)
