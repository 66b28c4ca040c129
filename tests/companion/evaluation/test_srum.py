"""SRUM against cases worked out by hand (REFERENCE.md section 1; ../shared/data/srum/README.md)."""

from __future__ import annotations

import json
import math

import pytest

from companion.errors import MerlionError
from companion.evaluation.datasets import load_dataset
from companion.evaluation.srum import SrumParams, human_score, pair_score, relative, score, srum, time_credit

E1 = math.exp(-1.0)
E3 = math.exp(-3.0)


@pytest.fixture
def labels() -> dict[int, frozenset[str]]:
    table = {f: frozenset() for f in range(1, 301)}
    table[10] = frozenset({"A"})
    table[100] = frozenset({"A"})
    table[200] = frozenset({"B"})
    table[250] = frozenset({"A", "B"})
    return table


def test_time_credit_is_full_inside_tau_and_decays_with_one_second_constant():
    assert time_credit(100, 160) == 1.0  # 60 frames = tau * fps exactly
    assert time_credit(160, 100) == 1.0
    assert time_credit(100, 190) == pytest.approx(E1)  # 30 frames past the edge
    assert time_credit(100, 100 + 60 + 45) == pytest.approx(math.exp(-1.5))
    assert time_credit(0, 20, SrumParams(fps=10)) == 1.0
    assert time_credit(0, 30, SrumParams(fps=10)) == pytest.approx(E1)


def test_pair_needs_a_shared_label_and_empty_never_matches(labels):
    assert pair_score(10, 100, labels) == pytest.approx(0.5 + 0.5 * E1)
    assert pair_score(10, 200, labels) == 0.0
    assert pair_score(250, 200, labels) == 1.0
    assert pair_score(5, 6, labels) == 0.0  # two frames without fish do not match
    assert pair_score(10, 100, labels, SrumParams(alpha=1.0)) == 1.0
    assert pair_score(10, 100, labels, SrumParams(alpha=0.0)) == pytest.approx(E1)


def test_score_takes_the_best_automatic_frame_per_human_frame_with_fixed_denominator(labels):
    # best(100) = max(pair(10,100), pair(250,100)) = 0.5 + 0.5/e; best(200) = 1 via 250; best(5) = 0.
    expected = (0.5 + 0.5 * E1 + 1.0 + 0.0) / 3
    assert score([10, 250], [100, 200, 5], labels) == pytest.approx(expected)
    # many-to-one: order and duplicates of the automatic summary do not matter
    assert score([250, 10, 10, 250], [100, 200, 5], labels) == pytest.approx(expected)
    assert score([], [100], labels) == 0.0


def test_srum_is_the_mean_over_humans_and_human_score_is_leave_one_out(labels):
    humans = {"h1": [100, 200], "h2": [250], "h3": [10]}
    auto = [250]
    s1 = (0.5 + 0.5 * E3 + 1.0) / 2  # 100 vs 250: share A, 150 frames -> exp(-3)
    assert srum(auto, humans, labels) == pytest.approx((s1 + 1.0 + (0.5 + 0.5 * math.exp(-6))) / 3)
    # leave-one-out by hand
    h1 = (score([100, 200], [250], labels) + score([100, 200], [10], labels)) / 2
    h2 = (score([250], [100, 200], labels) + score([250], [10], labels)) / 2
    h3 = (score([10], [100, 200], labels) + score([10], [250], labels)) / 2
    assert h1 == pytest.approx((1.0 + (0.5 + 0.5 * E1)) / 2)
    assert human_score(humans, labels) == pytest.approx((h1 + h2 + h3) / 3)
    assert relative(0.25, 0.5) == pytest.approx(50.0)


def test_bad_inputs_are_one_line_errors(labels):
    with pytest.raises(MerlionError, match="frame 999"):
        score([999], [100], labels)
    with pytest.raises(MerlionError, match="at least 2"):
        human_score({"only": [100]}, labels)
    with pytest.raises(MerlionError, match="alpha"):
        SrumParams(alpha=1.5)
    with pytest.raises(MerlionError, match="fps"):
        SrumParams(fps=0)
    with pytest.raises(MerlionError, match="tau"):
        SrumParams(tau_s=float("nan"))  # NaN slipped past "< 0"
    with pytest.raises(MerlionError, match="fps"):
        SrumParams(fps=float("nan"))


@pytest.mark.parametrize(("change", "message"), [
    ({"frame_labels": 5}, "frame_labels must be an object, got int 5"),  # was AttributeError
    ({"human_summaries": 3}, "human_summaries must be an object, got int 3"),
    ({"frame_labels": {"1": ["fish"], "2": 5}}, "frame_labels.2 must be a list of label names, got 5"),  # not "key '2'"
    ({"frame_labels": {"1": "fish"}}, "frame_labels.1 must be a list of label names, got 'fish'"),
    ({"fps": "abc"}, "fps must be a positive number, got 'abc'"),  # was ValueError
    ({"fps": 0}, "fps must be a positive number, got 0"),
])
def test_a_malformed_data_set_json_is_one_line_naming_the_key(tmp_path, change, message):
    data = {"frame_labels": {"1": ["fish"], "2": []}, "human_summaries": {"h1": [1]}, "fps": 30}
    data.update(change)
    f = tmp_path / "set.json"
    f.write_text(json.dumps(data))
    with pytest.raises(MerlionError) as info:
        load_dataset(f)
    assert str(info.value) == f"{f}: {message}"
