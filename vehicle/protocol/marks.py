"""The marks file (/config/marks.json): the operator's "more like this" / "not this" on summary frames, read by
the vehicle, written by the surface (the page's buttons, ``merlion surface-mark``, any MAVLink FTP client).

JSON ``{"like": [image_index...], "unlike": [image_index...]}``. Everything from the wire is bounded: the file's
size and the number of marks on each side; an index may not be on both sides.
"""

from __future__ import annotations

import json

MARKS_PATH = "/config/marks.json"
MARKS_MAX_BYTES = 2048
"""A marks file names a few summary frames; anything larger is not a marks file."""
MARKS_MAX = 32
"""Marks per kind ("like" or "unlike"): a handful teaches the scorer; more only slows the re-encoding."""


def parse_marks(data: bytes) -> tuple[list[int], list[int]]:
    """A marks file: JSON ``{"like": [image_index...], "unlike": [image_index...]}``; ValueError says what is wrong.

    Both lists may be empty (that clears the marks); an index may not be on both sides.
    """
    if len(data) > MARKS_MAX_BYTES:
        raise ValueError(f"marks file is {len(data)} bytes, more than {MARKS_MAX_BYTES}")
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"marks file is not JSON ({err})") from None
    if not isinstance(doc, dict):
        raise ValueError('marks file must be an object {"like": [...], "unlike": [...]}')
    extra = sorted(set(doc) - {"like", "unlike"})
    if extra:
        raise ValueError(f"marks file: unknown key {extra[0]!r} (expected like, unlike)")
    sides: list[list[int]] = []
    for key in ("like", "unlike"):
        value = doc.get(key, [])
        if not isinstance(value, list) or not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0
                                                  for i in value):
            raise ValueError(f"marks file: {key} must be a list of image indices (integers >= 0)")
        if len(value) > MARKS_MAX:
            raise ValueError(f"marks file: {len(value)} {key} marks, more than {MARKS_MAX}")
        sides.append(list(dict.fromkeys(value)))
    both = sorted(set(sides[0]) & set(sides[1]))
    if both:
        raise ValueError(f"marks file: image {both[0]} is both like and unlike")
    return sides[0], sides[1]


def format_marks(like: list[int], unlike: list[int]) -> bytes:
    return json.dumps({"like": list(like), "unlike": list(unlike)}).encode()


def marks_text(like: list[int], unlike: list[int]) -> str:
    """The STATUSTEXT that confirms marks in force."""
    return f"Marks: {len(like)} like, {len(unlike)} unlike"
