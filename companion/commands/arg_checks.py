"""Range checks for command-line numbers, one message style for every command.

argparse's ``type=float`` takes "nan" and "inf" too; a plain ``value <= 0`` test lets NaN through (every
comparison with NaN is false), so the checks here say what is allowed rather than what is not.
"""

from __future__ import annotations

import math
import socket

from companion.errors import UsageError


def require_positive(option: str, value: float | None) -> None:
    """``option`` (e.g. "--duration") must be a finite number above zero when it is given."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{option} {value}: must be positive")


def require_non_negative(option: str, value: float | None) -> None:
    """``option`` must be a finite number, zero or more, when it is given."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise UsageError(f"{option} {value}: must be zero or more")


def require_resolvable_host(option: str, connection: str) -> None:
    """A MAVLink connection's host must resolve now: an unknown name would otherwise open "fine" and wait forever
    (udpout sends nowhere, udpin listens on nothing). Serial devices have no host."""
    # pymavlink + numpy, 0.2-0.4 s measured: only when a connection is checked, not on every merlion call
    from vehicle.link.endpoint import parse_connection

    endpoint = parse_connection(connection)
    if endpoint.scheme == "serial":
        return
    host, _, port = endpoint.address.rpartition(":")
    try:
        socket.getaddrinfo(host, int(port), type=socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as err:
        reason = getattr(err, "strerror", None) or str(err)
        raise UsageError(f"{option} {connection}: cannot resolve host {host!r} ({reason})") from None
