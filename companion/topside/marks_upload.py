"""Send the operator's marks to the companion: /config/marks.json over MAVLink FTP, with the project's own FTP
client (``station_upload``), the one the surface tool uses.

The companion checks the file when the upload's session closes: it answers the closing request with an ACK and a
STATUSTEXT ``Marks: ...``, or with a NAK and ``Marks refused: why`` (a frame it no longer stores, a malformed
file). The file is checked with the vehicle's own parser before anything is sent.
"""

from __future__ import annotations

from companion.config import MavlinkConfig
from companion.errors import MerlionError, UsageError
from companion.topside.station_upload import upload_file
from vehicle.protocol.marks import MARKS_PATH, format_marks, parse_marks

__all__ = ["MARKS_PATH", "marks_document", "upload_marks"]

ANSWERS = ("Marks",)
"""The companion's STATUSTEXT answers to a marks upload (``Marks: ...``, ``Marks refused: ...``)."""


def marks_document(like: list[int], unlike: list[int]) -> bytes:
    """The marks file for these image indices; ValueError (as the companion would refuse it) when malformed."""
    data = format_marks(like, unlike)
    parse_marks(data)
    return data


def upload_marks(connect: str, cfg: MavlinkConfig, target: tuple[int, int], like: list[int], unlike: list[int],
                 *, timeout: float = 15.0) -> list[str]:
    """Upload the marks over a connection of our own to the companion ``target`` (system, component); returns
    its status lines. Raises MerlionError naming what failed (no answer, or the companion refused them)."""
    try:
        data = marks_document(like, unlike)
    except ValueError as err:  # checked here, before anything is sent: bad input
        raise UsageError(str(err)) from None
    answer = upload_file(connect, cfg, target, MARKS_PATH, data, answers=ANSWERS, timeout=timeout,
                         name="surface-mark")
    if not answer.accepted:
        said = "; ".join(answer.status) or f"FTP {answer.error}"
        raise MerlionError(f"the companion refused the marks {data.decode()}: {said} (a marked image it no longer "
                           f"stores, or surface.ftp_writable off?)")
    return answer.status
