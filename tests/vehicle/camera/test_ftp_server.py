"""MAVLink FTP: the server core against the spec's rules, then pymavlink's mavftp client over real UDP (with loss)."""

from __future__ import annotations

import json
import struct

import pytest
from pymavlink import mavftp

from tests.vehicle.surface_env import LossyRelay, ground_station
from vehicle.camera.ftp_server import FtpServer, VirtualTree, clean_path, crc32_ardupilot
from vehicle.protocol.ftp import MAX_DATA, FtpErr, FtpPacket, Op

WHO = (255, 190)


def _strict(name: str):
    raise ValueError(f"{name} is not JSON a browser accepts")


def _req(op: int, seq: int = 10, *, session: int = 0, offset: int = 0, data: bytes = b"", size=None) -> bytes:
    pkt = FtpPacket(seq, session, op, offset=offset, data=data)
    if size is not None:
        pkt.size_override = size
    return pkt.pack()


def _one(server: FtpServer, payload: bytes, who=WHO) -> FtpPacket:
    replies = server.handle(payload, who)
    assert len(replies) == 1
    assert len(replies[0]) == 251
    return FtpPacket.unpack(replies[0])


@pytest.fixture
def tree() -> VirtualTree:
    t = VirtualTree()
    t.put("/summary/1.jpg", bytes(range(256)) * 3)
    t.put("/summary/index.json", b'{"summary":[]}')
    return t


def test_replies_follow_the_spec(tree):
    server = FtpServer(tree)
    opened = _one(server, _req(Op.OPEN_FILE_RO, 41, data=b"/summary/1.jpg\0"))
    assert (opened.opcode, opened.req_opcode, opened.seq) == (Op.ACK, Op.OPEN_FILE_RO, 42)
    assert struct.unpack("<I", opened.data) == (768,)
    read = _one(server, _req(Op.READ_FILE, 42, session=opened.session, offset=700, size=200))
    assert (read.req_opcode, read.seq, read.offset, read.data) == (Op.READ_FILE, 43, 700, tree.read("/summary/1.jpg")[700:])
    full = _one(server, _req(Op.READ_FILE, 43, session=opened.session, offset=0, size=0))
    assert len(full.data) == MAX_DATA
    eof = _one(server, _req(Op.READ_FILE, 44, session=opened.session, offset=768, size=100))
    assert (eof.opcode, eof.data) == (Op.NAK, bytes([FtpErr.EOF]))
    done = _one(server, _req(Op.TERMINATE_SESSION, 45, session=opened.session))
    assert (done.opcode, done.req_opcode, done.seq) == (Op.ACK, Op.TERMINATE_SESSION, 46)
    # the same TerminateSession again (its ACK was lost): answered again, not refused
    assert _one(server, _req(Op.TERMINATE_SESSION, 45, session=opened.session)).opcode == Op.ACK
    # a fresh terminate of a closed session is refused
    assert _one(server, _req(Op.TERMINATE_SESSION, 47, session=opened.session)).opcode == Op.NAK


def test_retransmitted_open_gets_the_same_session(tree):
    server = FtpServer(tree)
    first = _one(server, _req(Op.OPEN_FILE_RO, 7, data=b"/summary/1.jpg\0"))
    again = _one(server, _req(Op.OPEN_FILE_RO, 7, data=b"/summary/1.jpg\0"))
    assert first.session == again.session and server.retransmits_answered == 1


def test_sessions_are_per_client_and_numbered_as_asked(tree):
    server = FtpServer(tree)
    a = _one(server, _req(Op.OPEN_FILE_RO, 1, session=0, data=b"/summary/1.jpg"), who=(255, 190))
    b = _one(server, _req(Op.OPEN_FILE_RO, 1, session=0, data=b"/summary/index.json"), who=(254, 190))
    c = _one(server, _req(Op.OPEN_FILE_RO, 5, session=7, data=b"/summary/index.json"), who=(255, 190))
    assert (a.session, b.session, c.session) == (0, 0, 7)  # MAVSDK 4 keeps using the number it asked with
    read_a = _one(server, _req(Op.READ_FILE, 2, session=0, size=4), who=(255, 190))
    read_b = _one(server, _req(Op.READ_FILE, 2, session=0, size=4), who=(254, 190))
    assert (read_a.data, read_b.data) == (bytes(range(4)), b'{"su')
    assert _one(server, _req(Op.READ_FILE, 3, session=1, size=4), who=(255, 190)).data == bytes(
        [FtpErr.INVALID_SESSION])


def test_a_cached_answer_replays_only_the_very_same_request(tree):
    server = FtpServer(tree)
    first = _one(server, _req(Op.OPEN_FILE_RO, 7, data=b"/summary/1.jpg\0"))
    assert struct.unpack("<I", first.data)[0] == 768
    # a restarted client (or another session) reuses seq 7 for another file: it gets that file, not the cache
    _one(server, _req(Op.TERMINATE_SESSION, 8))
    other = _one(server, _req(Op.OPEN_FILE_RO, 7, data=b"/summary/index.json\0"))
    assert struct.unpack("<I", other.data)[0] == 14 and server.retransmits_answered == 0
    # the same bytes from another requester are that requester's own request
    _one(server, _req(Op.OPEN_FILE_RO, 7, data=b"/summary/index.json\0"), who=(254, 190))
    assert server.retransmits_answered == 0
    # and a reset forgets what was cached for the client that reset
    _one(server, _req(Op.RESET_SESSIONS, 9))
    assert _one(server, _req(Op.READ_FILE, 3, size=4)).data == bytes([FtpErr.INVALID_SESSION])


def test_sessions_are_not_shared_and_a_full_table_naks(tree):
    clock = [0.0]
    server = FtpServer(tree, max_sessions=2, clock=lambda: clock[0])
    _one(server, _req(Op.OPEN_FILE_RO, 1, session=0, data=b"/summary/1.jpg"), who=(1, 1))
    _one(server, _req(Op.OPEN_FILE_RO, 1, session=1, data=b"/summary/1.jpg"), who=(2, 1))
    stolen = _one(server, _req(Op.READ_FILE, 2, session=0, size=4), who=(2, 1))  # client 1's session number
    assert (stolen.opcode, stolen.data) == (Op.NAK, bytes([FtpErr.INVALID_SESSION]))
    full = _one(server, _req(Op.OPEN_FILE_RO, 1, session=3, data=b"/summary/1.jpg"), who=(3, 1))
    assert (full.opcode, full.data) == (Op.NAK, bytes([FtpErr.NO_SESSIONS_AVAILABLE]))
    assert server.naks[FtpErr.NO_SESSIONS_AVAILABLE] == 1
    # the opener's own old session makes room; so does one idle for long (its client is gone)
    assert _one(server, _req(Op.OPEN_FILE_RO, 4, session=5, data=b"/summary/1.jpg"), who=(2, 1)).opcode == Op.ACK
    clock[0] = 100.0
    assert _one(server, _req(Op.OPEN_FILE_RO, 5, session=3, data=b"/summary/1.jpg"), who=(3, 1)).opcode == Op.ACK


def test_refusals_and_failures_are_naks_never_silence(tree):
    class Refused(Exception):
        """Not a ValueError: what the app raises for a queries file it rejects."""

    def refuse(data: bytes) -> None:
        raise Refused("no negative queries")

    def disk_full(data: bytes) -> None:
        raise OSError(28, "No space left on device")

    tree.uploadable("/config/queries.txt", refuse)
    tree.uploadable("/config/other.txt", disk_full)
    tree.put("/summary/broken.jpg", lambda: 1 // 0)
    rw = FtpServer(tree, writable=True)
    for seq, target, expected in ((1, b"/config/queries.txt", bytes([FtpErr.FAIL])),
                                  (11, b"/config/other.txt", bytes([FtpErr.FAIL_ERRNO, 28]))):
        made = _one(rw, _req(Op.CREATE_FILE, seq, data=target))
        _one(rw, _req(Op.WRITE_FILE, seq + 1, session=made.session, data=b"only one line\n"))
        done = _one(rw, _req(Op.TERMINATE_SESSION, seq + 2, session=made.session))
        assert (done.opcode, done.req_opcode, done.data) == (Op.NAK, Op.TERMINATE_SESSION, expected)
    broken = _one(rw, _req(Op.OPEN_FILE_RO, 4, data=b"/summary/broken.jpg"))
    assert (broken.opcode, broken.data) == (Op.NAK, bytes([FtpErr.FAIL]))
    assert _one(rw, _req(Op.LIST_DIRECTORY, 5, data=b"/nowhere")).data == bytes([FtpErr.FILE_NOT_FOUND])
    assert _one(FtpServer(tree), _req(Op.CREATE_DIRECTORY, 6, data=b"/x")).data == bytes([FtpErr.FILE_PROTECTED])


def test_listing_uses_size_metadata_and_never_produces_files():
    produced = []
    t = VirtualTree()
    t.put("/frames/1.jpg", lambda: produced.append(1) or b"x" * 50, size=lambda: 50)
    t.put("/frames/2.jpg", lambda: produced.append(2) or b"y" * 9)
    listing = _one(FtpServer(t), _req(Op.LIST_DIRECTORY, data=b"/frames"))
    assert listing.data == b"F1.jpg\t50\0F2.jpg\t0\0" and produced == []


def test_burst_streams_the_file_with_advancing_seq(tree):
    server = FtpServer(tree)
    opened = _one(server, _req(Op.OPEN_FILE_RO, 1, data=b"/summary/1.jpg"))
    assert server.handle(_req(Op.BURST_READ_FILE, 2, session=opened.session, size=80), WHO) == []
    got = []
    while (nxt := server.next_burst()) is not None:
        assert nxt[0] == WHO
        got.append(FtpPacket.unpack(nxt[1]))
    assert [p.seq for p in got] == [3, 4, 5, 6]
    assert [p.burst_complete for p in got] == [False, False, False, True]
    assert b"".join(p.data for p in got) == tree.read("/summary/1.jpg")


def test_list_paths_and_escapes(tree):
    server = FtpServer(tree)
    root = _one(server, _req(Op.LIST_DIRECTORY, data=b"/\0"))
    assert root.data == b"Dsummary\0"
    listing = _one(server, _req(Op.LIST_DIRECTORY, data=b"/summary\0junk-after-nul"))
    assert listing.data == b"F1.jpg\t768\0Findex.json\t14\0"
    assert _one(server, _req(Op.LIST_DIRECTORY, offset=2, data=b"/summary")).data == bytes([FtpErr.EOF])
    assert clean_path("/summary/../../etc/passwd") is None
    for path in (b"/summary/../../etc/passwd", b"../summary/1.jpg", b"/nope.txt"):
        reply = _one(server, _req(Op.OPEN_FILE_RO, data=path))
        assert (reply.opcode, reply.data) == (Op.NAK, bytes([FtpErr.FILE_NOT_FOUND]))
    crc = _one(server, _req(Op.CALC_FILE_CRC32, data=b"/summary/index.json"))
    assert struct.unpack("<I", crc.data)[0] == crc32_ardupilot(b'{"summary":[]}')
    assert _one(server, _req(Op.RENAME, data=b"/a\0/b")).data == bytes([FtpErr.UNKNOWN_COMMAND])


def test_writes_only_when_writable(tree):
    uploads = []
    tree.uploadable("/config/queries.txt", uploads.append)
    ro = FtpServer(tree)
    assert _one(ro, _req(Op.CREATE_FILE, data=b"/config/queries.txt")).data == bytes([FtpErr.FILE_PROTECTED])
    rw = FtpServer(tree, writable=True)
    assert _one(rw, _req(Op.CREATE_FILE, data=b"/summary/1.jpg")).data == bytes([FtpErr.FILE_PROTECTED])
    made = _one(rw, _req(Op.CREATE_FILE, 1, data=b"/config/queries.txt"))
    assert made.opcode == Op.ACK
    w = _one(rw, _req(Op.WRITE_FILE, 2, session=made.session, offset=4, data=b"fish"))
    assert (w.opcode, w.offset) == (Op.ACK, 4)
    _one(rw, _req(Op.WRITE_FILE, 3, session=made.session, offset=0, data=b"see "))
    assert uploads == []
    assert _one(rw, _req(Op.TERMINATE_SESSION, 4, session=made.session)).opcode == Op.ACK
    assert uploads == [b"see fish"]


# ---- pymavlink's mavftp client over real UDP ----------------------------------------------------------------

def _settings(**over) -> mavftp.MAVFTPSettings:
    values = {"debug": 0, "pkt_loss_tx": 0, "pkt_loss_rx": 0, "max_backlog": 5, "burst_read_size": 239,
              "write_size": 80, "write_qsize": 5, "idle_detection_time": 1.5, "read_retry_time": 0.6,
              "retry_time": 0.4}
    values.update(over)
    return mavftp.MAVFTPSettings([(k, type(v), v) for k, v in values.items()])


def _get(client: mavftp.MAVFTP, remote: str, local) -> bool:
    client.cmd_get([remote, str(local)])
    ret = client.process_ftp_reply("OpenFileRO", timeout=20)
    return ret.error_code == mavftp.FtpError.Success and local.exists()


def test_mavftp_lists_and_downloads(companion, tmp_path):
    port, surface = companion
    gcs = ground_station(port)
    try:
        client = mavftp.MAVFTP(gcs, 1, 100, settings=_settings())
        listing = client.cmd_list(["/summary"])
        assert listing.error_code == mavftp.FtpError.Success
        names = {e.name: e.size_b for e in client.list_result}
        assert names == {"3.jpg": len(surface.tree.read("/summary/3.jpg")), "4.jpg": names["4.jpg"],
                         "5.jpg": names["5.jpg"], "full": 0, "index.json": names["index.json"]}
        assert _get(client, "/summary/4.jpg", tmp_path / "4.jpg")
        assert (tmp_path / "4.jpg").read_bytes() == surface.tree.read("/summary/4.jpg")
        assert _get(client, "/summary/index.json", tmp_path / "index.json")
        index = json.loads((tmp_path / "index.json").read_text(), parse_constant=_strict)
        assert [e["image_index"] for e in index["summary"]] == [5, 4, 3]
        assert index["summary"][0]["pose"]["depth_m"] == 12.5
        # size and CRC of each thumbnail, so a surface tool checks a pushed one without a CalcFileCRC32 request
        four = next(e for e in index["summary"] if e["image_index"] == 4)
        got = (tmp_path / "4.jpg").read_bytes()
        assert (four["thumbnail_bytes"], four["thumbnail_crc32"]) == (len(got), crc32_ardupilot(got))
        assert all(e["thumbnail_crc32"] == crc32_ardupilot(surface.tree.read(e["thumbnail"])) for e in index["summary"])
        assert _get(client, "/summary/full/5.jpg", tmp_path / "full5.jpg")
        assert (tmp_path / "full5.jpg").read_bytes()[:2] == b"\xff\xd8"
        assert client.cmd_crc(["/summary/3.jpg"]).error_code == mavftp.FtpError.Success
    finally:
        gcs.close()


def test_uploading_queries_changes_them_live(companion, tmp_path):
    port, surface = companion
    changed = []
    surface.on_queries_changed(lambda topics: changed.append([(t.name, t.positive, list(t.negatives)) for t in topics]))
    local = tmp_path / "queries.txt"
    local.write_text("underwater image with a crab\nunderwater image of sand\nunderwater image of rocks\n")
    gcs = ground_station(port)
    try:
        client = mavftp.MAVFTP(gcs, 1, 100, settings=_settings())
        client.cmd_put([str(local), "/config/queries.txt"])
        assert client.process_ftp_reply("put", timeout=10).error_code == mavftp.FtpError.Success
        assert changed == [[("main", "underwater image with a crab",
                             ["underwater image of sand", "underwater image of rocks"])]]
        assert _get(client, "/config/queries.txt", tmp_path / "back.txt")
        assert "with a crab" in (tmp_path / "back.txt").read_text()
        assert "[" not in (tmp_path / "back.txt").read_text()  # one default topic: the simple form
        for bad in ("only a positive query\n",  # a topic needs a negative too: refused, nothing changes
                    "[Big Fish]\nfish\nno fish\n",  # not a topic name
                    "[a]\nfish\nno fish\n[a]\ncoral\nsand\n"):  # a name used twice
            local.write_text(bad)
            client.cmd_put([str(local), "/config/queries.txt"])
            client.process_ftp_reply("put", timeout=10)
        assert len(changed) == 1
        assert b"with a crab" in surface.tree.read("/config/queries.txt")
        local.write_text("[fish]\nunderwater image with fish\nunderwater image without fish\n"
                         "[coral]\nunderwater image of a coral reef\nunderwater image of sand\n")
        client.cmd_put([str(local), "/config/queries.txt"])
        assert client.process_ftp_reply("put", timeout=10).error_code == mavftp.FtpError.Success
        assert [t[0] for t in changed[-1]] == ["fish", "coral"]
        assert changed[-1][1] == ("coral", "underwater image of a coral reef", ["underwater image of sand"])
        back = surface.tree.read("/config/queries.txt").decode()
        assert "[fish]" in back and "[coral]" in back
        index = json.loads(surface.tree.read("/summary/index.json"))
        assert [t["name"] for t in index["topics"]] == ["fish", "coral"]
    finally:
        gcs.close()


def test_every_thumbnail_arrives_intact_through_a_lossy_link(companion, tmp_path):
    port, surface = companion
    relay = LossyRelay(port, loss=0.15)
    gcs = ground_station(relay.port)
    try:
        client = None
        for _ in range(5):  # the reset handshake itself may be lost
            client = mavftp.MAVFTP(gcs, 1, 100, settings=_settings())
            if client.pending_reset_seq is None:
                break
        for idx in (3, 4, 5):
            local = tmp_path / f"{idx}.jpg"
            for _attempt in range(8):  # a client retries a failed download, as an operator would
                if _get(client, f"/summary/{idx}.jpg", local) and local.read_bytes() == surface.tree.read(
                        f"/summary/{idx}.jpg"):
                    break
            assert local.read_bytes() == surface.tree.read(f"/summary/{idx}.jpg")
        assert relay.dropped > 0
    finally:
        gcs.close()
        relay.close()
