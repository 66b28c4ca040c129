"""Refused unsigned writes from many made-up ids: the first is logged in full, the rest counted in one line per
interval (issue 46's flood from 200 ids wrote 200 WARNING lines), while every source is still counted in the stats."""

from __future__ import annotations

import logging
import re
import socket

from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.link.connection import MavLink
from vehicle.link.signing import LinkSigning, key_from_bytes
from vehicle.protocol.ftp import FtpPacket, Op

KEY = key_from_bytes(b"reef survey\n")
IDS = 200


def _ftp_write(system: int) -> mav2.MAVLink_message:
    """An unsigned FTP WriteFile from ``system``/190 to the camera 1/100, packed and parsed as the link sees it."""
    packer = mav2.MAVLink(None, srcSystem=system, srcComponent=190)
    ftp = FtpPacket(1, 0, Op.WRITE_FILE, data=b"x" * 40)
    packet = mav2.MAVLink_file_transfer_protocol_message(0, 1, 100, list(ftp.pack())).pack(packer)
    return mav2.MAVLink(None).parse_buffer(packet)[0]


def _lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "FTP write" in r.getMessage()]


def test_a_flood_of_made_up_ids_is_one_line_then_a_count_per_interval(caplog):
    caplog.set_level(logging.WARNING, logger="vehicle")
    now = [100.0]
    signing = LinkSigning(KEY, name="camera")
    signing.refusal_log.clock = lambda: now[0]
    for system in range(10, 10 + IDS):
        for _ in range(3):
            assert not signing.admit(_ftp_write(system), lambda m: 0, (1, 100))
    assert _lines(caplog) == [_lines(caplog)[0]]
    assert "unsigned FTP write from 10/190 ignored" in _lines(caplog)[0]
    assert len(signing.rejected) == IDS and sum(signing.rejected.values()) == 3 * IDS  # every source still counted
    signing.refusal_log.flush()  # within the interval: nothing yet
    assert len(_lines(caplog)) == 1
    now[0] += signing.refusal_log.interval_s
    signing.refusal_log.flush()
    lines = _lines(caplog)
    assert len(lines) == 2
    assert f"from {IDS - 1} more sources" in lines[1] and f"unsigned FTP write from {9 + IDS}/190 ignored" in lines[1]
    assert signing.refusal_log.withheld == IDS - 1
    now[0] += 3 * signing.refusal_log.interval_s
    signing.refusal_log.flush()  # nothing new: no line
    assert len(_lines(caplog)) == 2
    signing.admit(_ftp_write(240), lambda m: 0, (1, 100))  # a new spell after a quiet interval: in full again
    assert len(_lines(caplog)) == 3 and "unsigned FTP write from 240/190 ignored" in _lines(caplog)[2]
    signing.admit(_ftp_write(241), lambda m: 0, (1, 100))
    now[0] += signing.refusal_log.interval_s
    signing.admit(_ftp_write(242), lambda m: 0, (1, 100))  # the interval is over: counted and said at once
    assert len(_lines(caplog)) == 4 and "from 2 more sources" in _lines(caplog)[3]


def test_the_links_timer_says_the_count_when_the_flood_has_stopped(tmp_path, caplog):
    """Real UDP: 200 made-up ids send unsigned FTP writes to a signed MavLink, then fall silent; the link's own timer
    thread logs the count (nothing else arrives to trigger it)."""
    caplog.set_level(logging.WARNING, logger="vehicle")
    key_file = tmp_path / "key"
    key_file.write_text("reef survey\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file)), heartbeat=False)
    link.subscribe(lambda m: None, ["FILE_TRANSFER_PROTOCOL"])
    link.signing.refusal_log.interval_s = 1.0
    link.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert link.wait_open(5)
        for system in range(10, 10 + IDS):
            sock.sendto(_ftp_write(system).get_msgbuf(), ("127.0.0.1", port))
        assert wait_until(lambda: len(link.signing.rejected) == IDS, 20)

        def counted() -> int:
            return sum(int(m.group(1)) for line in _lines(caplog) if (m := re.search(r"from (\d+) more source", line)))

        assert wait_until(lambda: counted() == IDS - 1, 20), _lines(caplog)
        lines = _lines(caplog)
        assert "unsigned FTP write from 10/190 ignored" in lines[0]
        assert len(lines) <= 1 + 20, lines  # at most a line per interval of the flood's few seconds, not per id
        assert link.stats()["signing"]["rejected"] == IDS
    finally:
        sock.close()
        link.stop()
