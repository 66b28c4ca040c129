"""The FTP wire format that the on-board server and the topside client share (vehicle/protocol/ftp.py)."""

from __future__ import annotations

from vehicle.protocol.ftp import MAX_DATA, PAYLOAD_LEN, FtpErr, FtpPacket, Op, ack, crc32_ardupilot, nak


def test_a_request_round_trips_with_its_size_and_path():
    raw = FtpPacket.request(0xFFFF, 3, Op.READ_FILE, offset=70000, size=200)
    assert len(raw) == PAYLOAD_LEN and raw[:12] == bytes.fromhex("ffff0305c8000000" "70110100")
    back = FtpPacket.unpack(raw)
    assert (back.seq, back.session, back.opcode, back.offset, back.size) == (0xFFFF, 3, Op.READ_FILE, 70000, 200)
    opened = FtpPacket.unpack(FtpPacket.request(1, 0, Op.OPEN_FILE_RO, data=b"/summary/index.json\0junk"))
    assert opened.path() == "/summary/index.json"


def test_replies_echo_the_request_and_naks_say_why():
    req = FtpPacket.unpack(FtpPacket.request(0xFFFF, 2, Op.OPEN_FILE_RO, data=b"/x"))
    reply = ack(req, data=b"\x10\0\0\0")
    assert (reply.seq, reply.req_opcode, reply.opcode, reply.session) == (0, Op.OPEN_FILE_RO, Op.ACK, 2)
    missing = FtpPacket.unpack(nak(req, FtpErr.FILE_NOT_FOUND).pack())
    assert (missing.opcode, missing.data, missing.error_text()) == (Op.NAK, bytes([10]), "file not found")
    full = FtpPacket.unpack(nak(req, FtpErr.FAIL_ERRNO, errno=28).pack())
    assert (full.data, full.error_text()) == (bytes([FtpErr.FAIL_ERRNO, 28]), "errno 28")
    assert MAX_DATA == 239


def test_crc32_is_ardupilots():
    """ArduPilot's crc_crc32(0, ...): reflected polynomial 0xEDB88320, register starts at 0, no final xor."""
    def bitwise(data: bytes) -> int:
        crc = 0
        for byte in data:
            crc ^= byte
            for _ in range(8):
                crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
        return crc

    for data in (b"123456789", bytes(range(256)) * 3, b""):
        assert crc32_ardupilot(data) == bitwise(data)
    assert crc32_ardupilot(b"123456789") == 0x2DFD2D88
