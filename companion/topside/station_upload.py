"""One file uploaded to the companion over MAVLink FTP by a surface command, on a connection of its own.

The project's own message-driven FTP client (``ftp_client.FtpClient``, the one the surface tool uses) does the
transfer: it reports a NAK of the closing request (the companion checks an uploaded file when its session closes,
and refuses a bad one there), and a small receive loop here also hears the companion's STATUSTEXT answers.
``surface-queries`` and ``surface-mark`` both upload through it.
"""

from __future__ import annotations

import queue
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig
from companion.errors import MerlionError
from companion.topside.ftp_client import FtpClient
from vehicle.link.connection import MavLink

ANSWER_WAIT_S = 3.0
"""After the ACK or NAK, how long the companion's status line may still take (it is sent at status priority,
so it usually arrives first)."""


@dataclass
class UploadAnswer:
    """What the companion made of the upload."""

    accepted: bool
    error: str = ""
    """Why the upload failed (the FTP client's words: ``refused: ...``, ``create failed: ...``), when it did."""
    status: list[str] = field(default_factory=list)
    """The companion's STATUSTEXT lines that start with one of the ``answers`` asked for."""


def upload_file(connect: str, cfg: MavlinkConfig, target: tuple[int, int], path: str, data: bytes, *,
                answers: tuple[str, ...] = (), timeout: float = 15.0, name: str = "surface-upload") -> UploadAnswer:
    """Upload ``data`` to ``path`` on the companion ``target`` and wait for its ACK or NAK and for a status line
    starting with one of ``answers``. MerlionError when it never answered within ``timeout``."""
    inbox: queue.Queue = queue.Queue()
    link = MavLink(connect, cfg, name=name, mav_type=mav.MAV_TYPE_GCS)
    link.subscribe(inbox.put, types=("FILE_TRANSFER_PROTOCOL", "STATUSTEXT"))

    def send(system: int, component: int, payload: bytes) -> None:
        link.send(mav.MAVLink_file_transfer_protocol_message(0, system, component, list(payload)))

    result: list[tuple[bytes | None, str]] = []
    status: list[str] = []
    client = FtpClient(send, target, own=(cfg.system_id, cfg.component_id), max_timeout_s=2.0, max_tries=1000)
    deadline = time.monotonic() + timeout
    link.start()
    try:
        if not link.wait_open(min(5.0, timeout)):
            raise MerlionError(f"--connect {connect}: the connection did not open")
        client.upload(path, data, lambda _path, got, error: result.append((got, error)))
        answered_at: float | None = None
        while time.monotonic() < deadline:
            if result and answered_at is None:
                answered_at = time.monotonic()
            if answered_at is not None and (status or not answers or time.monotonic() - answered_at > ANSWER_WAIT_S):
                break
            try:
                msg = inbox.get(timeout=0.05)
            except queue.Empty:
                client.tick()
                continue
            if (msg.get_srcSystem(), msg.get_srcComponent()) != target:
                continue
            if msg.get_type() == "FILE_TRANSFER_PROTOCOL":
                client.handle(msg)
            else:
                text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else msg.text
                text = text.rstrip("\0")
                if answers and text.startswith(answers):
                    status.append(text)
            client.tick()
    finally:
        link.stop()
    if not result:
        raise MerlionError(f"no answer from the companion {target[0]}:{target[1]} within {timeout:g} s")
    got, error = result[0]
    return UploadAnswer(accepted=got is not None, error=error, status=status)
