"""companion.evaluation.roc against hand-computed cases."""

from __future__ import annotations

import pytest

from companion.evaluation.roc import auroc


def test_perfect_inverted_and_hand_counted_rankings():
    assert auroc([0.9, 0.8, 0.2, 0.1], [1, 1, 0, 0]) == 1.0
    assert auroc([0.9, 0.8, 0.2, 0.1], [0, 0, 1, 1]) == 0.0
    # positives 0.7, 0.3; negatives 0.5, 0.1: pairs won (0.7>0.5, 0.7>0.1, 0.3>0.1) = 3 of 4
    assert auroc([0.7, 0.5, 0.3, 0.1], [1, 0, 1, 0]) == 0.75


def test_ties_count_half():
    assert auroc([0.5, 0.5], [1, 0]) == 0.5
    # positive 0.5 ties one negative (0.5) and beats another (0.2): (0.5 + 1) / 2
    assert auroc([0.5, 0.5, 0.2], [1, 0, 0]) == 0.75


def test_undefined_cases_are_refused():
    with pytest.raises(ValueError, match="needs both classes"):
        auroc([0.1, 0.2], [1, 1])
    with pytest.raises(ValueError, match="2 scores but 3 labels"):
        auroc([0.1, 0.2], [1, 0, 1])
