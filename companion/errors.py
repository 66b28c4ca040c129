"""The one domain error of the command line: its message is the single line the user sees.

The class itself lives in ``vehicle.errors`` (the side that imports nothing from the app), so a bad tlog or a bad
connection string from ``vehicle/`` is the same error as a bad video from ``companion/``.
"""

from __future__ import annotations

from vehicle.errors import UsageError
from vehicle.errors import UserError as MerlionError

__all__ = ["MerlionError", "UsageError"]
