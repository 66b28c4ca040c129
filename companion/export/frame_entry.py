"""One frame entry of a store's or a summary's ``summary.json``, read field by field for an export.

Read with bare ``int()``/``float()``, a damaged entry (a width of "abc", a score of null, an index of 1e400) ended
``merlion export`` in a traceback. Each field is checked here instead: a value of the wrong kind is a one-line
``UsageError`` that names the file, the entry and the field, and nothing is written (the store is only read). A
field that is only informative (the topic, the query) and not text is left out rather than written as Python's
repr of it.
"""

from __future__ import annotations

import math
from pathlib import Path, PurePosixPath
from typing import Any

from companion.errors import UsageError


class FrameEntry:
    """``frames[position]`` of ``doc`` (a summary.json); every accessor raises UsageError naming it."""

    def __init__(self, doc: Path, position: int, data: Any) -> None:
        self.where = f"{doc}: frames[{position}]"
        if not isinstance(data, dict):
            raise UsageError(f"{self.where}: not an object")
        self.data = data
        file = data.get("file")
        if isinstance(file, str):
            self.where += f" ({file})"

    def _bad(self, key: str, what: str) -> UsageError:
        return UsageError(f"{self.where}: {key} {self.data.get(key)!r:.40} is not {what}")

    def whole(self, key: str, default: int) -> int:
        """A whole number >= 0 (``default`` when absent)."""
        value = self.data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self._bad(key, "a whole number")
        return value

    def size(self, key: str) -> int | None:
        """A width or height: a whole number > 0, or None when absent (then read from the image)."""
        value = self.data.get(key)
        if value is None or value == 0:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self._bad(key, "a whole number of pixels")
        return value

    def number(self, key: str, default: float) -> float:
        """A finite number (``default`` when absent)."""
        value = self.data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self._bad(key, "a number")
        return float(value)

    def text(self, key: str, data: Any = None) -> str:
        """Text from this entry (or from ``data``, a part of it such as its tags); "" when absent or not text."""
        value = (self.data if data is None else data).get(key)
        return value if isinstance(value, str) else ""

    def image(self, folder: Path) -> Path:
        """The entry's image file: a relative path inside ``folder`` that exists, with no symbolic link on the way
        (a link in a store would have an export point at, and hash, a file outside it: /etc/hostname)."""
        file = self.data.get("file")
        if file is None:
            raise UsageError(f"{self.where}: no 'file'")
        parts = PurePosixPath(file).parts if isinstance(file, str) else ()
        if not parts or PurePosixPath(file).is_absolute() or ".." in parts:
            raise self._bad("file", "a path inside the folder")
        image = folder / file
        for depth in range(1, len(parts) + 1):
            if folder.joinpath(*parts[:depth]).is_symlink():
                raise UsageError(f"{folder.joinpath(*parts[:depth])}: a symbolic link; an export follows none")
        if not image.is_file():
            raise UsageError(f"{image}: frame image missing")
        return image
