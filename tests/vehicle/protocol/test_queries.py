"""The queries file: one topic in the simple form, several with [name] lines, and every bound enforced."""

from __future__ import annotations

import pytest

from vehicle.protocol.queries import MAX_BYTES, MAX_TOPICS, QueryTopic, format_queries, parse_queries


def test_the_simple_form_is_one_default_topic():
    topics = parse_queries(b"# comment\r\nunderwater image with fish\n\nunderwater image without fish\n", "main")
    assert topics == [QueryTopic("main", "underwater image with fish", ("underwater image without fish",))]
    text = format_queries(topics, "main")
    assert "[" not in text and parse_queries(text, "main") == topics


def test_several_topics_round_trip():
    topics = [QueryTopic("fish", "underwater image with fish", ("underwater image without fish",)),
              QueryTopic("coral_reef", "a coral reef", ("sand", "rocks"))]
    text = format_queries(topics, "main")
    assert "[fish]" in text and "[coral_reef]" in text
    assert parse_queries(text.encode(), "main") == topics
    # one topic that is not the default keeps its name
    assert parse_queries(format_queries(topics[1:], "main"), "main") == topics[1:]


@pytest.mark.parametrize(("data", "words"), [
    (b"only a positive\n", "at least one negative"),
    (b"", "needs a positive"),
    (b"[fish]\nfish\n", "topic fish: needs"),
    (b"[Fish]\nfish\nno fish\n", "topic name 'Fish'"),
    (b"[a/b]\nfish\nno fish\n", "topic name 'a/b'"),
    (b"[a]\nfish\nno\n[a]\ncoral\nsand\n", "used twice"),
    (b"\xff\xfe\n", "not UTF-8"),
    (b"x" * 301 + b"\nno\n", "longer than 300"),
    (b"a\n" * (MAX_BYTES // 2 + 1), f"more than {MAX_BYTES}"),
    ("".join(f"[t{i}]\npos\nneg\n" for i in range(MAX_TOPICS + 1)).encode(), f"more than {MAX_TOPICS}"),
    (b"pos\n" + b"neg\n" * 17, "more than 16"),
    (b"fish\x00\x00\nsand\n", "^control character U\\+0000$"),  # the surface would show "fish", the store a NUL
    (b"fish\nsand\x1b[2J\n", "^control character U\\+001B$"),
])
def test_bad_files_are_refused_with_a_reason(data, words):
    with pytest.raises(ValueError, match=words):
        parse_queries(data, "main")
