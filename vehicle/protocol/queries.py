"""The queries file (/config/queries.txt): the topics the camera follows, read by the vehicle, written by the surface.

Plain text so an operator can write it in any editor and upload it with any MAVLink FTP client (MAVProxy's
``ftp put``, QGroundControl, ``merlion surface-queries``)::

    # one topic: the first line is the positive query, the following lines its negatives
    underwater image with fish
    underwater image without fish

Several topics, each followed at once with its own summary, start with a ``[name]`` line::

    [fish]
    underwater image with fish
    underwater image without fish
    [coral]
    underwater image of a coral reef
    underwater image of sand

Everything from the wire is bounded: the file's size, the number of topics, the length of a line, and names
(lower-case letters, digits, ``-`` and ``_``, at most 24: they end up in paths and 50-character STATUSTEXTs).
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass

MAX_BYTES = 8192
MAX_TOPICS = 8
MAX_LINE = 300
MAX_NEGATIVES = 16
NAME = re.compile(r"^[a-z0-9][a-z0-9_-]{0,23}$")
_HEADER = re.compile(r"^\[(.*)\]$")


@dataclass(frozen=True)
class QueryTopic:
    """One topic as the file states it."""

    name: str
    positive: str
    negatives: tuple[str, ...]


def parse_queries(data: bytes | str, default_name: str) -> list[QueryTopic]:
    """The topics a queries file lists (``default_name`` names a file without ``[name]`` lines).

    ValueError says, in one line, what is wrong (the surface sees it as a STATUSTEXT and a NAK).
    """
    if isinstance(data, bytes):
        if len(data) > MAX_BYTES:
            raise ValueError(f"queries file is {len(data)} bytes, more than {MAX_BYTES}")
        try:
            data = data.decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError("queries file is not UTF-8 text") from None
    control = next((c for c in data if unicodedata.category(c) == "Cc" and c not in "\n\r\t"), None)
    if control is not None:  # a NUL would reach the encoder and the store while the surface shows the text before it
        raise ValueError(f"control character U+{ord(control):04X}")  # short: a STATUSTEXT holds 50
    lines = [ln.strip() for ln in data.replace("\r", "").split("\n")]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    groups: list[tuple[str, list[str]]] = []
    for line in lines:
        header = _HEADER.match(line)
        if header:
            name = header.group(1).strip()
            if not NAME.match(name):
                raise ValueError(f"topic name {name!r}: use lower-case letters, digits, - and _ (at most 24)")
            groups.append((name, []))
            continue
        if len(line) > MAX_LINE:
            raise ValueError(f"a query line is longer than {MAX_LINE} characters")
        if not groups:
            groups.append((default_name, []))
        groups[-1][1].append(line)
    if not groups:
        raise ValueError("a queries file needs a positive line and at least one negative line")
    if len(groups) > MAX_TOPICS:
        raise ValueError(f"queries file lists {len(groups)} topics, more than {MAX_TOPICS}")
    topics = []
    for name, queries in groups:
        if len(queries) < 2:
            raise ValueError(f"topic {name}: needs a positive line and at least one negative line")
        if len(queries) - 1 > MAX_NEGATIVES:
            raise ValueError(f"topic {name}: {len(queries) - 1} negatives, more than {MAX_NEGATIVES}")
        if any(t.name == name for t in topics):
            raise ValueError(f"topic name {name!r} is used twice")
        topics.append(QueryTopic(name, queries[0], tuple(queries[1:])))
    return topics


def format_queries(topics: list[QueryTopic], default_name: str) -> str:
    """The file for these topics; the one default topic is written without a ``[name]`` line (the simple form)."""
    if len(topics) == 1 and topics[0].name == default_name:
        t = topics[0]
        return "# first line: positive query; following lines: negative queries\n" + "\n".join(
            [t.positive, *t.negatives]) + "\n"
    out = ["# [name] starts a topic; its first line is the positive query, the following lines its negatives"]
    for t in topics:
        out += [f"[{t.name}]", t.positive, *t.negatives]
    return "\n".join(out) + "\n"
