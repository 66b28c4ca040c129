"""Send the operator's marks to the companion: /config/marks.json over MAVLink FTP, then read it back.

The companion answers an upload it refuses (a frame it no longer stores, a malformed file) with a NAK and a
STATUSTEXT; pymavlink's mavftp does not report a NAK of the closing request, so the upload is confirmed by
reading the file back: it equals what was sent only if the companion accepted it.
"""

from __future__ import annotations

import io
import json
import tempfile
import time
from pathlib import Path

from pymavlink import mavftp, mavutil

from companion.errors import MerlionError
from vehicle.camera.downlink import MARKS_PATH, format_marks, parse_marks

__all__ = ["MARKS_PATH", "marks_document", "upload_marks"]

_FTP_SETTINGS = {"debug": 0, "pkt_loss_tx": 0, "pkt_loss_rx": 0, "max_backlog": 5, "burst_read_size": 239,
                 "write_size": 200, "write_qsize": 5, "idle_detection_time": 1.5, "read_retry_time": 0.6,
                 "retry_time": 0.4}


def marks_document(like: list[int], unlike: list[int]) -> bytes:
    """The marks file for these image indices; ValueError (as the companion would refuse it) when malformed."""
    data = format_marks(like, unlike)
    parse_marks(data)
    return data


def _wait(deadline: float) -> float:
    """How long one mavftp exchange may take: what is left, but more than its idle detection (it asserts so)."""
    return max(_FTP_SETTINGS["idle_detection_time"] + 0.5, min(10.0, deadline - time.monotonic()))


def upload_marks(conn: mavutil.mavfile, target: tuple[int, int], like: list[int], unlike: list[int], *,
                 timeout: float = 15.0) -> None:
    """Upload the marks through ``conn`` to the companion ``target`` (system, component) and confirm them.

    Raises MerlionError naming what failed (no answer, or the companion kept its old marks: it refused these).
    """
    try:
        data = marks_document(like, unlike)
    except ValueError as err:
        raise MerlionError(str(err)) from None
    settings = mavftp.MAVFTPSettings([(k, type(v), v) for k, v in _FTP_SETTINGS.items()])
    client = mavftp.MAVFTP(conn, target[0], target[1], settings=settings)
    deadline = time.monotonic() + timeout
    with tempfile.TemporaryDirectory(prefix="merlion-marks-") as tmp:
        back = Path(tmp) / "marks.json"
        while time.monotonic() < deadline:  # a request lost on the link: the whole exchange again
            client.cmd_put(["marks.json", MARKS_PATH], fh=io.BytesIO(data))
            client.process_ftp_reply("CreateFile", timeout=_wait(deadline))
            back.unlink(missing_ok=True)
            client.cmd_get([MARKS_PATH, str(back)])
            got = client.process_ftp_reply("OpenFileRO", timeout=_wait(deadline))
            if got.error_code != mavftp.FtpError.Success or not back.exists():
                continue
            try:
                held = json.loads(back.read_text(encoding="utf-8"))
            except ValueError:
                continue
            if held == json.loads(data):
                return
            raise MerlionError(f"the companion refused the marks {data.decode()} (it keeps {json.dumps(held)}): "
                               f"a marked image it no longer stores, or surface.ftp_writable off? its STATUSTEXT says why")
    raise MerlionError(f"no answer from the companion {target[0]}:{target[1]} within {timeout:g} s "
                       f"(is surface.ftp_writable on?)")
