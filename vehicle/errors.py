"""The one error a user can fix, for every ``merlion`` command, MAVLink side and app side alike.

Defined here, on the side that imports nothing, so that ``vehicle/`` raises the same error the command line turns
into one ``merlion: error: ...`` line; ``companion.errors`` re-exports it as ``MerlionError``.
"""

from __future__ import annotations


class UserError(Exception):
    """A problem the user can fix (a missing file, a bad value, an unreachable endpoint).

    The message names what is wrong (file, key, value) in one line; ``exit_code`` is what ``merlion`` exits with.
    """

    exit_code: int = 1

    def __init__(self, message: str, *, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class UsageError(UserError):
    """Bad arguments or configuration, found before anything started."""

    exit_code = 2
