"""The surface FTP client against the companion's real FTP server, over real UDP, with and without loss."""

from __future__ import annotations

import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.topside.ftp_client import FtpClient, crc32_mavftp
from tests.companion.surface_peer import CompanionPeer, summary_frame

OWN = (254, 190)


class _Client:
    """An FtpClient on its own UDP socket, its receive loop in this test's thread."""

    def __init__(self, burst: bool = True) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.peer = CompanionPeer(self.sock.getsockname()[1])
        self.tx = mav.MAVLink(None, srcSystem=OWN[0], srcComponent=OWN[1])
        self.rx = mav.MAVLink(None)
        self.ftp = FtpClient(self._send, (1, 100), own=OWN, min_timeout_s=0.2, max_timeout_s=1.0,
                             burst=burst)
        self.results: dict[str, tuple[bytes | None, str]] = {}
        self.done = threading.Event()

    def _send(self, system: int, component: int, payload: bytes) -> None:
        msg = mav.MAVLink_file_transfer_protocol_message(0, system, component, list(payload))
        self.sock.sendto(msg.pack(self.tx), self.peer.sock.getsockname())

    def fetch(self, *paths: str, timeout: float = 20.0) -> dict[str, tuple[bytes | None, str]]:
        for p in paths:
            self.ftp.fetch(p, lambda path, data, err: self.results.__setitem__(path, (data, err)))
        self.pump(lambda: len(self.results) >= len(paths), timeout)
        return self.results

    def pump(self, until, timeout: float = 20.0) -> None:
        """Be the receive loop: feed replies to the client and let it retransmit, until ``until()``."""
        end = time.monotonic() + timeout
        while not until() and time.monotonic() < end:
            try:
                data = self.sock.recv(4096)
                for msg in self.rx.parse_buffer(data) or []:
                    self.ftp.handle(msg)
            except TimeoutError:
                pass
            self.ftp.tick()

    def close(self) -> None:
        self.peer.close()
        self.sock.close()


def test_fetches_thumbnails_and_index_intact():
    c = _Client()
    try:
        sent = {i: c.peer.add(summary_frame(i), push=False) for i in (1, 2)}
        got = c.fetch("/summary/1.jpg", "/summary/2.jpg", "/summary/index.json", "/summary/99.jpg")
    finally:
        c.close()
    assert got["/summary/1.jpg"] == (sent[1], "")
    assert got["/summary/2.jpg"] == (sent[2], "")
    assert b'"image_index": 2' in got["/summary/index.json"][0]
    assert got["/summary/99.jpg"][0] is None and "not found" in got["/summary/99.jpg"][1]
    assert c.ftp.files_done == 3 and not c.ftp.busy


@pytest.mark.parametrize("burst", [True, False], ids=["burst", "read"])
def test_every_byte_arrives_when_the_link_drops_a_third_of_the_replies(burst):
    c = _Client(burst=burst)
    try:
        sent = c.peer.add(summary_frame(3), push=False)
        c.peer.drop_ftp_reply = lambda n: n % 3 == 0
        got = c.fetch("/summary/3.jpg")
    finally:
        c.close()
    assert got["/summary/3.jpg"] == (sent, "")
    assert c.peer.ftp_replies >= 3  # so at least one reply was dropped on the way
    assert c.ftp.retransmissions >= 1
    if not burst:
        assert c.peer.ftp.retransmits_answered >= 1  # a lost reply was asked for again with the same request


def test_only_the_bytes_a_stalled_push_lost_are_read():
    c = _Client()
    try:
        sent = c.peer.add(summary_frame(8), push=False)
        known = {off: sent[off:off + 253] for off in range(0, len(sent), 253) if off != 253}  # chunk 1 lost
        stale = {0: b"\0" * 253}
        results = {}
        c.ftp.fetch("/summary/8.jpg", lambda p, d, e: results.__setitem__("partial", (d, e)),
                    known=known, known_size=len(sent))
        c.ftp.fetch("/summary/8.jpg", lambda p, d, e: results.__setitem__("other size", (d, e)),
                    known=stale, known_size=len(sent) + 1)  # from a different file: not used
        c.pump(lambda: len(results) == 2)
    finally:
        c.close()
    assert results["partial"] == (sent, "") and results["other size"] == (sent, "")
    assert c.ftp.bytes_read == 253 + len(sent)  # the lost chunk, then the whole file for the second fetch


def test_crc_of_a_served_file_matches_ours():
    c = _Client()
    try:
        sent = c.peer.add(summary_frame(12), push=False)
        results = {}
        c.ftp.crc("/summary/12.jpg", lambda p, crc, e: results.__setitem__(p, (crc, e)))
        c.ftp.crc("/summary/13.jpg", lambda p, crc, e: results.__setitem__(p, (crc, e)))
        c.pump(lambda: len(results) == 2)
    finally:
        c.close()
    assert results["/summary/12.jpg"] == (crc32_mavftp(sent), "")
    assert results["/summary/13.jpg"][0] is None and "not found" in results["/summary/13.jpg"][1]


def test_an_upload_arrives_whole_through_loss_and_a_refusal_is_an_error():
    c = _Client()
    try:
        got: list[bytes] = []

        def take(data: bytes) -> None:
            if data.startswith(b"no"):
                raise ValueError("refused")
            got.append(data)

        c.peer.ftp.writable = True
        c.peer.tree.uploadable("/config/marks.json", take)
        c.peer.drop_ftp_reply = lambda n: n % 3 == 0
        data = bytes(range(256)) * 3  # several WriteFile pieces
        c.ftp.upload("/config/marks.json", data, lambda path, d, err: c.results.__setitem__("up", (d, err)))
        c.pump(lambda: "up" in c.results)
        assert c.results["up"] == (data, "")
        assert got == [data]
        c.ftp.upload("/config/marks.json", b"no thanks", lambda path, d, err: c.results.__setitem__("no", (d, err)))
        c.pump(lambda: "no" in c.results)
        assert c.results["no"][0] is None and c.results["no"][1].startswith("refused")
        assert got == [data]
    finally:
        c.close()
