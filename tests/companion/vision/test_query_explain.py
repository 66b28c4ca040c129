"""``--explain`` says when a learned head, not the classes listed, scores a query (``companion.vision.query_explain``)."""

from __future__ import annotations

from companion.vision.encoders.query_words import resolve_query
from companion.vision.query_explain import head_line


def test_fish_is_said_to_be_scored_by_the_fish_heads_and_a_place_beside_it_unread():
    assert head_line(resolve_query("fish")).startswith("  scored by the learned fish heads")
    line = head_line(resolve_query("fish near coral"))
    assert line is not None and line.endswith("where it is (coral) is not read by them")


def test_a_query_no_head_answers_gets_no_head_line():
    assert head_line(resolve_query("crab")) is None
    assert head_line(resolve_query("shark")) is None
