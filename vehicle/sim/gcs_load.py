"""A ground station that loads the companion the way a busy operator's laptop does, for the link stress proof.

Each instance is one independent client (its own socket, system id and pymavlink parser, meant to run in its own
process): for ``duration_s`` it lists /summary and /summary/full with pymavlink's ``mavftp``, downloads the
index, thumbnails and full frames, asks the server for each file's CRC-32, sets a parameter and uploads a
queries file the companion must refuse. It counts what a receiver can see going wrong: packets that fail their
CRC or length (pymavlink's ``total_receive_errors``), downloads that fail, and whether the refused upload was
answered with a NAK (and which error code) or not at all.
"""

from __future__ import annotations

import logging
import random
import tempfile
import time
from pathlib import Path
from typing import Any

from pymavlink import mavftp, mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.protocol.ftp import FtpPacket, Op, crc32_ardupilot

GCS_COMPONENT = 190
REFUSED_QUERIES = b"# one line only: the companion needs a positive and at least one negative query\nfish\n"
WELL_FORMED_QUERIES = b"underwater image of a crab\nunderwater image of sand\n"
"""Parses as a queries file; a companion whose app refuses it (the stress bench's does) must still NAK it."""


def _settings() -> mavftp.MAVFTPSettings:
    values = {"debug": 0, "pkt_loss_tx": 0, "pkt_loss_rx": 0, "max_backlog": 5, "burst_read_size": 239,
              "write_size": 80, "write_qsize": 5, "idle_detection_time": 1.5, "read_retry_time": 0.6,
              "retry_time": 0.5}
    return mavftp.MAVFTPSettings([(k, type(v), v) for k, v in values.items()])


class GroundStationLoad:
    """One client; ``run()`` returns its counts (see the module docstring)."""

    def __init__(self, connection: str, system_id: int, *, target: tuple[int, int] = (1, 100),
                 param: tuple[str, float, float] | None = None, seed: int = 0,
                 uploads: tuple[bytes, ...] = (REFUSED_QUERIES,)) -> None:
        self.gcs = mavutil.mavlink_connection(connection, source_system=system_id, source_component=GCS_COMPONENT,
                                              dialect="ardupilotmega")
        self.target = target
        self.param = param
        self.rng = random.Random(seed)
        self.uploads = uploads
        self.ftp = mavftp.MAVFTP(self.gcs, target[0], target[1], settings=_settings())
        self.result: dict[str, Any] = {"system_id": system_id, "lists": 0, "list_failures": 0, "downloads": {},
                                       "download_failures": 0, "server_crc": {}, "params_set": 0,
                                       "param_echoes": 0, "refused_upload": []}
        self._seq = 1000 + system_id * 7

    def hello(self) -> None:
        """A GCS heartbeat, so a udpin peer (or a router) learns where to answer."""
        self.gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def run(self, duration_s: float) -> dict[str, Any]:
        end = time.monotonic() + duration_s
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            self.hello()
            while time.monotonic() < end:
                self.hello()
                names = self._list("/summary")
                fulls = self._list("/summary/full")
                files = ["/summary/index.json"]
                files += [f"/summary/{n}" for n in names if n.endswith((".jpg", ".webp"))][:2]
                files += [f"/summary/full/{n}" for n in fulls][:1]
                for remote in files:
                    self._get(remote, folder)
                    if time.monotonic() >= end:
                        break
                self._set_param()
                self._refused_upload()
        self.result["corrupted"] = int(self.gcs.mav.total_receive_errors)
        self.result["received"] = int(self.gcs.mav.total_packets_received)
        self.gcs.close()
        return self.result

    # ---- FTP through pymavlink's client ---------------------------------------------------------------------
    def _list(self, path: str) -> list[str]:
        ret = self.ftp.cmd_list([path])
        if ret.error_code != mavftp.FtpError.Success:
            self.result["list_failures"] += 1
            return []
        self.result["lists"] += 1
        return [e.name for e in self.ftp.list_result if not e.is_dir]

    def _get(self, remote: str, folder: Path) -> None:
        local = folder / remote.strip("/").replace("/", "_")
        local.unlink(missing_ok=True)
        self.ftp.cmd_get([remote, str(local)])
        ret = self.ftp.process_ftp_reply("OpenFileRO", timeout=60)
        if ret.error_code != mavftp.FtpError.Success or not local.exists():
            self.result["download_failures"] += 1
            self.result.setdefault("failure_reasons", []).append(f"{remote}: {ret.error_code.name}")
            return
        data = local.read_bytes()
        crc = self._server_crc(remote)
        self.result["downloads"].setdefault(remote, []).append([len(data), crc32_ardupilot(data)])
        if crc is not None:
            self.result["server_crc"][remote] = crc

    # ---- raw requests where the answer itself is what is checked ---------------------------------------------
    def _request(self, opcode: int, *, session: int = 0, offset: int = 0, data: bytes = b"",
                 timeout: float = 3.0) -> FtpPacket | None:
        """Send one FTP request (retransmitted twice on silence); its reply, or None when none ever came."""
        self._seq = (self._seq + 1) & 0xFFFF
        payload = FtpPacket.request(self._seq, session, opcode, offset, data)
        for _ in range(3):
            self.gcs.mav.file_transfer_protocol_send(0, self.target[0], self.target[1], list(payload))
            end = time.monotonic() + timeout / 3
            while time.monotonic() < end:
                msg = self.gcs.recv_match(type="FILE_TRANSFER_PROTOCOL", blocking=True, timeout=0.1)
                if msg is None or msg.target_system != self.gcs.source_system:
                    continue
                reply = FtpPacket.unpack(msg.payload)
                if reply.req_opcode == opcode and reply.seq == (self._seq + 1) & 0xFFFF:
                    return reply
        return None

    def _server_crc(self, remote: str) -> int | None:
        reply = self._request(Op.CALC_FILE_CRC32, data=remote.encode())
        if reply is None or reply.opcode != Op.ACK or len(reply.data) < 4:
            return None
        return int.from_bytes(reply.data[:4], "little")

    def _refused_upload(self) -> None:
        """Create, write and close /config/queries.txt with a file the companion must refuse: the close's answer."""
        session = 3
        made = self._request(Op.CREATE_FILE, session=session, data=b"/config/queries.txt")
        if made is None or made.opcode != Op.ACK:
            self.result["refused_upload"].append("create: " + ("silence" if made is None else made.error_text()))
            return
        session = made.session
        body = self.uploads[self.rng.randrange(len(self.uploads))]
        wrote = self._request(Op.WRITE_FILE, session=session, data=body)
        if wrote is None or wrote.opcode != Op.ACK:
            self.result["refused_upload"].append("write: " + ("silence" if wrote is None else wrote.error_text()))
            return
        done = self._request(Op.TERMINATE_SESSION, session=session, timeout=6.0)
        if done is None:
            self.result["refused_upload"].append("silence")
        else:
            self.result["refused_upload"].append("ack" if done.opcode == Op.ACK else f"nak: {done.error_text()}")

    def _set_param(self) -> None:
        if self.param is None:
            return
        name, low, high = self.param
        value = float(self.rng.choice([low, high]))
        self.gcs.mav.param_set_send(self.target[0], self.target[1], name.encode(), value,
                                    mav.MAV_PARAM_TYPE_INT32)
        self.result["params_set"] += 1
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            msg = self.gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.1)
            if msg is not None and msg.param_id.rstrip("\0") == name:
                self.result["param_echoes"] += 1
                return


def run_client(connection: str, system_id: int, duration_s: float, param: tuple[str, float, float] | None,
               seed: int, results, uploads: tuple[bytes, ...] = (REFUSED_QUERIES,)) -> None:
    """Process entry point: run one client and put its result on ``results`` (a multiprocessing queue)."""
    logging.basicConfig(level=logging.ERROR)
    try:
        results.put(GroundStationLoad(connection, system_id, param=param, seed=seed, uploads=uploads).run(duration_s))
    except Exception as err:  # the parent reports it; a client that dies must not hang the proof
        results.put({"system_id": system_id, "error": repr(err)})
