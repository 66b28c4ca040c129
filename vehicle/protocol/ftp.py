"""MAVLink FTP wire format: the 12-byte header inside FILE_TRANSFER_PROTOCOL.payload, opcodes and error codes.

Kept apart from the server so the surface-side client and the tests share one definition of the bytes
(mavlink.io services/ftp: seq u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8, pad u8,
offset u32, then up to 239 data bytes; little endian).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251
"""FILE_TRANSFER_PROTOCOL.payload is always 251 bytes on the wire (zero padded)."""
MAX_DATA = PAYLOAD_LEN - HEADER.size
"""239: the most data bytes one FTP packet carries."""


class Op(IntEnum):
    NONE = 0
    TERMINATE_SESSION = 1
    RESET_SESSIONS = 2
    LIST_DIRECTORY = 3
    OPEN_FILE_RO = 4
    READ_FILE = 5
    CREATE_FILE = 6
    WRITE_FILE = 7
    REMOVE_FILE = 8
    CREATE_DIRECTORY = 9
    REMOVE_DIRECTORY = 10
    OPEN_FILE_WO = 11
    TRUNCATE_FILE = 12
    RENAME = 13
    CALC_FILE_CRC32 = 14
    BURST_READ_FILE = 15
    ACK = 128
    NAK = 129


class FtpErr(IntEnum):
    NONE = 0
    FAIL = 1
    FAIL_ERRNO = 2
    INVALID_DATA_SIZE = 3
    INVALID_SESSION = 4
    NO_SESSIONS_AVAILABLE = 5
    EOF = 6
    UNKNOWN_COMMAND = 7
    FILE_EXISTS = 8
    FILE_PROTECTED = 9
    FILE_NOT_FOUND = 10


ERROR_NAMES = {
    FtpErr.NONE: "none", FtpErr.FAIL: "fail", FtpErr.FAIL_ERRNO: "errno", FtpErr.INVALID_DATA_SIZE: "invalid data size",
    FtpErr.INVALID_SESSION: "invalid session", FtpErr.NO_SESSIONS_AVAILABLE: "no sessions available",
    FtpErr.EOF: "end of file", FtpErr.UNKNOWN_COMMAND: "unknown command", FtpErr.FILE_EXISTS: "file exists",
    FtpErr.FILE_PROTECTED: "file protected", FtpErr.FILE_NOT_FOUND: "file not found",
}
"""How a client words a NAK's error code."""


def crc32_ardupilot(data: bytes) -> int:
    """CRC-32 as ArduPilot and PX4 compute it for CalcFileCRC32 (reflected 0xEDB88320, start 0, no final xor)."""
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


@dataclass
class FtpPacket:
    """One FTP request or reply; ``data`` is the meaningful bytes (``size`` is derived from it)."""

    seq: int
    session: int
    opcode: int
    req_opcode: int = 0
    offset: int = 0
    data: bytes = b""
    burst_complete: bool = False
    size_override: int | None = None
    """Requests such as ReadFile carry a size with no data; replies never set this."""

    @property
    def size(self) -> int:
        return self.size_override if self.size_override is not None else len(self.data)

    def pack(self) -> bytes:
        """251 bytes ready for FILE_TRANSFER_PROTOCOL.payload."""
        if len(self.data) > MAX_DATA:
            raise ValueError(f"FTP data of {len(self.data)} bytes exceeds {MAX_DATA}")
        head = HEADER.pack(self.seq & 0xFFFF, self.session & 0xFF, self.opcode, self.size & 0xFF,
                           self.req_opcode, 1 if self.burst_complete else 0, 0, self.offset & 0xFFFFFFFF)
        return (head + self.data).ljust(PAYLOAD_LEN, b"\0")

    @classmethod
    def unpack(cls, payload: bytes | bytearray | list[int]) -> FtpPacket:
        """Parse a received payload; ``data`` is cut to the header's size (clamped to what is there)."""
        raw = bytes(payload)
        if len(raw) < HEADER.size:
            raise ValueError(f"FTP payload of {len(raw)} bytes is shorter than the {HEADER.size}-byte header")
        seq, session, opcode, size, req_opcode, burst, _pad, offset = HEADER.unpack_from(raw)
        data = raw[HEADER.size : HEADER.size + min(size, MAX_DATA)]
        pkt = cls(seq, session, opcode, req_opcode, offset, data, bool(burst))
        if size != len(data):
            pkt.size_override = size
        return pkt

    @classmethod
    def request(cls, seq: int, session: int, opcode: int, offset: int = 0, data: bytes = b"",
                size: int | None = None) -> bytes:
        """A client's request payload; ``size`` is for requests that carry a size but no data (ReadFile)."""
        pkt = cls(seq, session, opcode, offset=offset, data=data)
        if size is not None:
            pkt.size_override = size
        return pkt.pack()

    def error_text(self) -> str:
        """A NAK's error code in words ("file not found"; "errno 28" for Fail with an errno)."""
        code = self.data[0] if self.data else 0
        if code == FtpErr.FAIL_ERRNO and len(self.data) > 1:
            return f"errno {self.data[1]}"
        return ERROR_NAMES.get(code, f"error {code}")

    def path(self) -> str:
        """The request's path argument: data up to the first NUL, as UTF-8 (clients send ASCII)."""
        return self.data.split(b"\0", 1)[0].decode("utf-8", errors="replace")


def ack(request: FtpPacket, *, data: bytes = b"", session: int | None = None, offset: int | None = None,
        seq_step: int = 1, burst_complete: bool = False) -> FtpPacket:
    """A reply to ``request``: echoes its opcode, carries its seq + ``seq_step``."""
    return FtpPacket(
        seq=(request.seq + seq_step) & 0xFFFF,
        session=request.session if session is None else session,
        opcode=Op.ACK,
        req_opcode=request.opcode,
        offset=request.offset if offset is None else offset,
        data=data,
        burst_complete=burst_complete,
    )


def nak(request: FtpPacket, error: FtpErr, *, seq_step: int = 1, offset: int | None = None,
        errno: int | None = None) -> FtpPacket:
    """A negative reply carrying one error byte (two for ``FAIL_ERRNO``: the error and the errno)."""
    data = bytes([int(error)]) if errno is None else bytes([int(FtpErr.FAIL_ERRNO), errno & 0xFF])
    reply = ack(request, data=data, seq_step=seq_step, offset=offset)
    reply.opcode = Op.NAK
    return reply
