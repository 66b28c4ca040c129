"""The marks' weight choice (``group_feedback.choose_weight``): each frame order is a dive of its own."""

from __future__ import annotations

from companion.evaluation.group_feedback import MAX_LOSS, choose_weight


def test_a_weight_that_costs_a_group_too_much_in_one_order_is_not_chosen_though_its_mean_is_fine():
    # weight 4 gains most on average, and its mean over the two orders costs group b only 0.01, but one dive
    # (order 1) loses 0.03 on b: a dive made worse is not averaged away
    gains = {1.0: {0: {"a": 0.02, "b": 0.0}, 1: {"a": 0.02, "b": 0.0}},
             2.0: {0: {"a": 0.05, "b": 0.0}, 1: {"a": 0.05, "b": -0.015}},
             4.0: {0: {"a": 0.09, "b": 0.01}, 1: {"a": 0.09, "b": -MAX_LOSS - 0.01}}}
    assert choose_weight(gains) == 2.0
    assert choose_weight(gains, without="b") == 4.0  # chosen without the group that loses: nothing stops it


def test_among_near_equal_weights_the_lightest_and_when_none_qualifies_the_lightest():
    near = {1.0: {0: {"a": 0.040}}, 2.0: {0: {"a": 0.043}}, 3.0: {0: {"a": 0.044}}}
    assert choose_weight(near) == 1.0  # within TOLERANCE (0.005) of the best
    bad = {2.0: {0: {"a": -0.05}}, 3.0: {0: {"a": -0.04}}}
    assert choose_weight(bad) == 2.0
