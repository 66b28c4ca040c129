"""The one domain error of the command line: its message is the single line the user sees."""

from __future__ import annotations


class MerlionError(Exception):
    """A problem the user can fix (a missing file, a bad value, absent weights).

    The message names what is wrong (file, key, value) in one line; ``exit_code`` is what ``merlion`` exits with.
    """

    exit_code: int = 1

    def __init__(self, message: str, *, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class UsageError(MerlionError):
    """Bad arguments or configuration, found before anything started."""

    exit_code = 2
