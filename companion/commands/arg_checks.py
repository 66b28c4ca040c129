"""Range checks for command-line numbers and MAVLink ids, one message style for every command.

argparse's ``type=float`` takes "nan" and "inf" too; a plain ``value <= 0`` test lets NaN through (every
comparison with NaN is false), so the checks here say what is allowed rather than what is not.
"""

from __future__ import annotations

import argparse
import math

from companion.errors import UsageError


def require_positive(option: str, value: float | None) -> None:
    """``option`` (e.g. "--duration") must be a finite number above zero when it is given."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{option} {value}: must be positive")


def require_non_negative(option: str, value: float | None) -> None:
    """``option`` must be a finite number, zero or more, when it is given."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise UsageError(f"{option} {value}: must be zero or more")


def check_station_ids(system_id: int, component_id: int) -> None:
    """The ids a surface command speaks with: never 255, the pilot's ground station (its failsafes and its
    parameter writes would be attributed to this tool)."""
    if not 1 <= system_id <= 254:
        raise UsageError(f"--system-id {system_id}: must be 1-254 (255 is the pilot's ground station)")
    if not 1 <= component_id <= 255:
        raise UsageError(f"--component-id {component_id}: must be 1-255")


def companion_ids(text: str) -> tuple[int, int]:
    """``--companion SYS:COMP`` (argparse type): the companion's system and component ids."""
    try:
        system, component = (int(p) for p in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SYSTEM:COMPONENT such as 1:100, got {text!r}") from None
    if not (1 <= system <= 255 and 1 <= component <= 255):
        raise argparse.ArgumentTypeError(f"ids must be 1-255, got {text!r}")
    return system, component
