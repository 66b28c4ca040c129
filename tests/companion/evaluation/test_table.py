"""Table I of the paper recomputed from ../shared/data/srum, every value to the paper's printed precision."""

from __future__ import annotations

import math

import pytest

from companion.evaluation.datasets import load_dataset
from companion.evaluation.srum import human_score, srum
from companion.evaluation.table import TRUNCATED, compare_printed, compute_table, printed_decimals, table_json
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def cells():
    return compute_table(shared_file("srum/powellscay_low.json").parent)


def test_every_printed_value_is_reproduced(cells):
    reported = [c for c in cells if c.paper is not None]
    assert len(reported) == 13  # 5 + 5 + 3 entries printed in Table I
    for c in reported:
        d = printed_decimals(c.paper)
        assert d == (3 if c.dataset == "bonaire_moderate" else 4)
        if (c.dataset, c.column) in TRUNCATED:
            assert math.floor(c.ours * 10**d) / 10**d == pytest.approx(c.paper, abs=1e-12), c
            assert round(c.ours, d) != c.paper, "documented as truncated, but it rounds"
        else:
            assert round(c.ours, d) == pytest.approx(c.paper, abs=1e-12), c
    assert {(c.dataset, c.column) for c in cells if c.verdict == "truncated"} == TRUNCATED
    assert not [c for c in cells if c.verdict == "mismatch"]


def test_not_reported_cells_stay_empty(cells):
    js = table_json(cells)
    assert set(js) == {"powellscay_low", "bonaire_moderate", "kralendijk_clear"}
    assert js["kralendijk_clear"]["MERLION-E"] is None and js["kralendijk_clear"]["ROST-Enhanced"] is None
    assert js["powellscay_low"]["MERLION"] == pytest.approx(0.244584, abs=5e-7)


def test_clear_needs_all_sixteen_humans():
    ds = load_dataset(shared_file("srum/kralendijk_clear.json"))
    assert len(ds.paper_humans()) == 16 and len(ds.humans) == 14
    labels = ds.table.labels
    assert round(srum(ds.automatic["merlion"], ds.paper_humans(), labels), 4) == 0.4227
    assert round(srum(ds.automatic["merlion"], ds.humans, labels), 4) == 0.4223  # the script's 14: no match
    assert round(human_score(ds.humans, labels), 4) == 0.5592


def test_compare_printed_tells_rounding_from_truncation():
    assert compare_printed(0.244584, 0.2446) == (4, "rounded")
    assert compare_printed(0.406994, 0.4069) == (4, "truncated")
    assert compare_printed(0.4065, 0.4069) == (4, "mismatch")
    assert compare_printed(0.5208, 0.521) == (3, "rounded")
