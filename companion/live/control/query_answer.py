"""The companion's answer to a queries upload, in STATUSTEXT lines: what each query was read as, or why not.

The packaged encoder reads words through WordNet (``encoders.query_words``), so the operator must see on the
surface what "marine animal" became before trusting the summary; a word it cannot read is named in the refusal.
Lines are at most 50 characters (STATUSTEXT's text field); a file of many topics gets at most ``MAX_LINES``.
"""

from __future__ import annotations

from collections.abc import Sequence

from companion.errors import MerlionError
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.query_words import UnknownWord

WIDTH = 50
MAX_LINES = 6
"""STATUSTEXTs one upload may add (the page keeps the last 20; the link has a budget)."""


def resolution_lines(encoder: Encoder, topics: Sequence[tuple[str, Sequence[str]]]) -> list[str]:
    """For (topic name, [positive, *negatives]) pairs: one line per query the encoder resolves through words
    (``Query fish: fish=16: tench,goldfish,..``); empty for an encoder that embeds texts as written (CLIP)."""
    explain = getattr(encoder, "explain_texts", None)
    if explain is None:
        return []
    lines: list[str] = []
    queries = [(name, text) for name, texts in topics for text in texts if text.strip()]
    several = len(topics) > 1
    for name, text in queries:
        try:
            resolved = explain([text])[0]
        except MerlionError:
            continue  # the refusal says why; a generic negative the encoder cannot read is scored without
        lines.append(resolved.short(WIDTH, prefix=f"Query {name}: " if several else "Query "))
    if len(lines) > MAX_LINES:
        lines = lines[: MAX_LINES - 1] + [f"Query: and {len(lines) - MAX_LINES + 1} more (see the log)"]
    return lines


def refusal_line(topic: str, err: MerlionError) -> str:
    """``Queries refused: main: 'blorptang' unknown``: the word first, near words as they fit."""
    if isinstance(err, UnknownWord):
        return err.short(WIDTH, prefix=f"Queries refused: {topic}: ")
    return f"Queries refused: {topic}: {err}"[:WIDTH]
