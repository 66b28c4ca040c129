"""A hostile device on the tether: unsigned requests of every kind from many made-up ids, at a fixed rate.

The mix a helper used against the companion (issue 46): parameter lists and reads, FTP opens, lists, creates and
writes, COMMAND_LONG, PARAM_SET, heartbeats and garbage, from ``ids`` made-up system ids (component 190), none of
it signed. The datagrams are packed once beforehand (packing in Python costs more than sending), each id with its
own sequence numbers, and sent round robin from a few sockets (a device with several ports) at ``rate`` per
second, paced every 10 ms. ``send_flood`` is meant to run in a process of its own, so the flood does not share an
interpreter with the companion it floods.
"""

from __future__ import annotations

import random
import socket
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.protocol.ftp import FtpPacket, Op

KINDS = ("param_list", "param_read", "ftp_open", "ftp_list", "ftp_create", "ftp_write", "command", "param_set",
         "heartbeat", "garbage")
FIRST_ID = 10
"""Made-up system ids start here (clear of the autopilot's 1 and a ground station's 255)."""
COMPONENT = 190


def _request(kind: str, target: tuple[int, int], n: int, rng: random.Random) -> mav.MAVLink_message | None:
    """One request of ``kind`` (None for garbage, which is not a message); ``n`` varies it between rounds."""
    system, component = target
    if kind == "param_list":
        return mav.MAVLink_param_request_list_message(system, component)
    if kind == "param_read":
        return mav.MAVLink_param_request_read_message(system, component, b"", n % 8)
    if kind == "param_set":
        return mav.MAVLink_param_set_message(system, component, b"MERL_K", float(n % 30), mav.MAV_PARAM_TYPE_INT32)
    if kind == "command":
        return mav.MAVLink_command_long_message(system, component, mav.MAV_CMD_IMAGE_START_CAPTURE, 0,
                                                0, 0, 1, 0, 0, 0, 0)
    if kind == "heartbeat":
        return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
    if kind == "garbage":
        return None
    ftp = {"ftp_open": FtpPacket(n, 0, Op.OPEN_FILE_RO, data=b"/summary/index.json"),
           "ftp_list": FtpPacket(n, 0, Op.LIST_DIRECTORY, offset=n % 3, data=b"/summary"),
           "ftp_create": FtpPacket(n, 0, Op.CREATE_FILE, data=b"/config/queries.txt"),
           "ftp_write": FtpPacket(n, 0, Op.WRITE_FILE, data=rng.randbytes(40))}[kind]
    return mav.MAVLink_file_transfer_protocol_message(0, system, component, list(ftp.pack()))


def flood_datagrams(*, ids: int = 200, rounds: int = 4, target: tuple[int, int] = (1, 100),
                    seed: int = 0) -> list[bytes]:
    """``rounds`` of every kind from each of ``ids`` made-up ids, interleaved (id by id, kind by kind)."""
    rng = random.Random(seed)
    packers = [mav.MAVLink(None, srcSystem=FIRST_ID + i, srcComponent=COMPONENT) for i in range(ids)]
    out: list[bytes] = []
    for r in range(rounds):
        for kind in KINDS:
            for i, packer in enumerate(packers):
                msg = _request(kind, target, r * ids + i, rng)
                if msg is None:  # a MAVLink 2 start byte and a length, then noise
                    out.append(bytes([0xFD, rng.randrange(1, 255)]) + rng.randbytes(rng.randrange(4, 60)))
                    continue
                out.append(msg.pack(packer))
                packer.seq = (packer.seq + 1) % 256
    return out


def send_flood(port: int, rate: float, seconds: float, *, ids: int = 200, sockets: int = 4,
               results: Any = None) -> int:
    """Send the flood to 127.0.0.1:``port`` at ``rate`` datagrams/s for ``seconds``; how many were sent (also put
    on ``results``, a multiprocessing queue, when given)."""
    datagrams = flood_datagrams(ids=ids)
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(max(1, sockets))]
    sent = 0
    start = time.monotonic()
    try:
        while (elapsed := time.monotonic() - start) < seconds:
            due = int(elapsed * rate) + 1
            while sent < due:
                socks[sent % len(socks)].sendto(datagrams[sent % len(datagrams)], ("127.0.0.1", port))
                sent += 1
            time.sleep(0.01)
    finally:
        for s in socks:
            s.close()
    if results is not None:
        results.put(sent)
    return sent
