"""The surface tool against a sender without the key that makes its state grow: new dives without end, captures
no push ever comes for, and made-up sequence numbers under the vehicle's own ids. Real UDP sockets on 127.0.0.1,
real pymavlink messages, the real FTP server answering (helpers from ``test_hostile_link``)."""

from __future__ import annotations

import json
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.topside.gallery import Gallery
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.companion.topside.test_hostile_link import (
    Sender,
    _paced,
    _raw_capture,
    autopilot_heartbeat,
    meet,
    running_tool,
)
from tests.waiting import wait_until
from vehicle.protocol.ftp import FtpErr, FtpPacket, Op, nak


def _dive_capture(index: int, dive: str) -> mav.MAVLink_camera_image_captured_message:
    url = f"mftp://summary/{dive}/{index}.jpg".encode()
    return mav.MAVLink_camera_image_captured_message(0, 0, 0, 0, 0, 0, -12500, [1, 0, 0, 0], index, 1, url)


def test_dives_announced_without_end_keep_a_bounded_archive_and_gallery_json(tmp_path):
    """Each capture naming a dive never seen files the current one under ``dives/`` and was remembered for good:
    before, 600 made-up dives left 600 ids in ``dives`` and 600 archived captures (and 12,288 per dive when the
    sender filled each one first). Now 256 dive ids and the newest ``max_archived`` archived captures are kept,
    the oldest going first with their thumbnails."""
    from companion.topside.gallery import MAX_ARCHIVED, MAX_DIVES

    folder = tmp_path / "gallery"
    with running_tool(folder, Gallery(folder, max_archived=300)) as (tool, port):
        peer = CompanionPeer(port)
        peer.tree.remove("/summary/index.json")
        try:
            meet(peer)
            first = peer.add(summary_frame(1))  # a real frame with its thumbnail, in the first dive
            assert wait_until(lambda: (c := tool.gallery.get(1)) is not None and c.thumbnail is not None, 10)
            _paced(tool, peer, [_dive_capture(n, f"d{n:05d}") for n in range(600)], batch=200)
        finally:
            peer.close()
    assert first and MAX_DIVES == 256 and MAX_ARCHIVED == 4096
    gallery = tool.gallery
    assert gallery.dive == "d00599" and len(gallery.dives()) == MAX_DIVES
    assert gallery.dives()[-1] == "d00599" and "d00000" not in gallery.dives()
    archived = gallery.archived()
    assert len(archived) == 300 and [c.dive for c in archived][-1] == "d00598"
    assert gallery.archived_dropped == 600 - 300  # frame 1 of the first dive and 299 made-up ones
    assert not list((folder / "dives").rglob("*.jpg"))  # frame 1's thumbnail went with it
    doc = json.loads((folder / "gallery.json").read_text())
    assert len(doc["archived"]) == 300 and len(doc["dives"]) == MAX_DIVES and doc["archived_dropped"] == 300
    assert (folder / "gallery.json").stat().st_size < 250_000
    assert tool.snapshot()["archived_dropped"] == 300
    again = Gallery(folder, max_archived=300)  # reopened: the same bounds, the counters kept
    assert len(again.archived()) == 300 and again.archived_dropped == 300 and len(again.dives()) == MAX_DIVES



class SlowFtp:
    """The companion's real FTP server behind a slow link: each request is answered after ``delay`` seconds."""

    def __init__(self, ftp, delay: float) -> None:
        self.ftp, self.delay, self.opened = ftp, delay, []

    def handle(self, payload: bytes, requester) -> list[bytes]:
        packet = FtpPacket.unpack(payload)
        if packet.opcode == Op.OPEN_FILE_RO:
            self.opened.append(bytes(packet.data[: packet.size]).decode())
        time.sleep(self.delay)
        return self.ftp.handle(payload, requester)

    def next_burst(self):
        return self.ftp.next_burst()


def test_captures_no_push_comes_for_wait_in_bounded_queues_and_the_page_is_served(tmp_path):
    """2,000 captures announced and never pushed: before, all 2,000 waited for a push, and after the push timeout
    each became an FTP fetch queued at once; behind them, on a link answering a request every 20 ms, the page's
    full frame waited 40 s (it gives up after 120 s). Now 256 wait for a push (the rest go to the FTP queue
    at once), the thumbnails are fetched one at a time, and the page's request takes its turn after one of them."""
    from companion.topside.surface_state import MAX_WAITING

    with running_tool(tmp_path / "gallery", push_timeout_s=1.0) as (tool, port):
        peer = CompanionPeer(port)
        peer.tree.remove("/summary/index.json")
        peer.tree.put("/summary/full/1999.jpg", b"\xff\xd8full frame\xff\xd9")
        try:
            meet(peer)
            peer.ftp = slow = SlowFtp(peer.ftp, 0.02)
            _paced(tool, peer, [_raw_capture(n) for n in range(2000)], batch=250)
            assert len(tool.ctx.pairing.waiting) <= MAX_WAITING == 256
            time.sleep(1.5)  # every push timed out: all 2,000 want an FTP fetch
            assert wait_until(lambda: len(tool.ctx.pairing.waiting) == 0, 5)
            assert len(tool.ctx.ftp.pending()) <= 3  # the index, one thumbnail, a page request at most
            started = time.monotonic()
            full = tool.full_frame(1999, timeout=15)
            took = time.monotonic() - started
            assert full is not None and full.read_bytes() == b"\xff\xd8full frame\xff\xd9"
            assert took < 2.0
            assert wait_until(lambda: len(slow.opened) > 60, 10)  # the thumbnails are still fetched, in turn
        finally:
            peer.close()
    thumbs = [p for p in slow.opened if p.startswith("/summary/") and p[9:-4].isdigit()]
    assert thumbs[:3] == ["/summary/0.jpg", "/summary/1.jpg", "/summary/2.jpg"]  # the first announced first
    assert tool.status.ftp_failed >= 60  # not found: this companion has no such files


def test_each_ftp_lane_holds_64_requests_and_the_lanes_take_turns():
    """One requester's flood of fetches neither grows the client's queue for good nor keeps another's waiting."""
    from companion.topside.ftp_client import MAX_QUEUED, FtpClient

    sent: list[bytes] = []
    client = FtpClient(lambda _s, _c, payload: sent.append(payload), (1, 100))
    outcomes: list[tuple[str, str]] = []
    for n in range(MAX_QUEUED + 11):  # the first goes out at once; 64 wait; 10 are refused
        client.fetch(f"/summary/{n}.jpg", lambda path, _data, error: outcomes.append((path, error)),
                     lane="thumbnails")
    client.fetch("/summary/full/7.jpg", lambda *_: None, lane="page")
    assert MAX_QUEUED == 64 and client.refused == 10 and len(client.pending()) == 1 + 64 + 1
    assert [p for p, _ in outcomes] == [f"/summary/{n}.jpg" for n in range(65, 75)]
    assert all(e.startswith("refused:") for _, e in outcomes)
    packer, parser, opened = mav.MAVLink(None, srcSystem=1, srcComponent=100), mav.MAVLink(None), []
    for _ in range(3):  # each open NAKed (not found): the next request is the other lane's
        request = FtpPacket.unpack(sent[-1])
        opened.append(bytes(request.data[: request.size]).decode())
        reply = nak(request, FtpErr.FILE_NOT_FOUND).pack()
        client.handle(parser.decode(bytearray(
            mav.MAVLink_file_transfer_protocol_message(0, 254, 190, list(reply)).pack(packer))))
    assert opened == ["/summary/0.jpg", "/summary/full/7.jpg", "/summary/1.jpg"]


@pytest.fixture
def surface(tmp_path):
    with running_tool(tmp_path / "gallery") as running:
        yield running


def _jumping(sender: Sender, msg, count: int) -> None:
    """``count`` messages from ``sender``, each 100 sequence numbers after the last: 99 "lost" packets apiece."""
    for _ in range(count):
        sender.send(msg)
        sender.mav.seq = (sender.mav.seq + 99) % 256


def test_made_up_sequence_numbers_under_the_vehicles_own_ids_count_nothing_from_another_address(surface):
    """Without a key the ids are free: a device sending under the autopilot's and the companion's ids, 100
    sequence numbers apart, made 99 "lost" packets a message (40 messages: 3,960). Now the sequence of each is
    followed only from the address its identity was learnt from; the rest is counted apart."""
    tool, port = surface
    autopilot, spoofer = Sender(port, 1, 1), Sender(port, 1, 1)
    peer = CompanionPeer(port)
    value = mav.MAVLink_named_value_float_message(0, b"MRL_FPS", 5.0)
    try:
        autopilot.send(autopilot_heartbeat())
        meet(peer)
        peer.add(summary_frame(1), push=False)  # the companion is known
        assert wait_until(lambda: tool.status.companion == (1, 100) and tool.status.autopilot == (1, 1), 10)
        sent = tool.status.messages
        _jumping(spoofer, autopilot_heartbeat(), 20)
        spoofer.mav.srcComponent = 100
        _jumping(spoofer, value, 20)
        autopilot.mav.seq += 4  # the vehicle's own losses still count: four
        autopilot.send(autopilot_heartbeat())
        peer.mav.seq += 3  # and the companion's: three
        peer.values(MRL_FPS=4.0)
        assert wait_until(lambda: tool.status.messages >= sent + 42, 10)
    finally:
        autopilot.close()
        spoofer.close()
        peer.close()
    link = tool.snapshot()["link"]
    assert link["lost_packets"] == 7
    assert link["other_address_messages"] == 40


def test_with_a_key_unsigned_messages_under_the_companions_ids_count_no_lost_packets(tmp_path):
    """With a signing key, only what the connection verified is followed: an unsigned device sending under the
    signed companion's ids with made-up sequence numbers adds nothing to ``lost_packets``."""
    from companion.config import MavlinkConfig
    from vehicle.link.connection import MavLink

    key = tmp_path / "signing.key"
    key.write_text("reef survey 17\n")
    with running_tool(tmp_path / "gallery", signing_key_file=str(key)) as (tool, port):
        companion = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100,
                                                                       signing_key_file=str(key)), name="companion")
        companion.start()
        spoofer = Sender(port, 1, 100)
        try:
            assert wait_until(lambda: tool.status.messages > 0, 10)  # its signed heartbeat: a camera
            companion.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"started"))
            assert wait_until(lambda: tool.status.companion == (1, 100), 10)
            _jumping(spoofer, mav.MAVLink_named_value_float_message(0, b"MRL_FPS", 5.0), 40)
            assert wait_until(lambda: tool.status.unsigned_ignored >= 40, 10)
            companion.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"still here"))
            assert wait_until(lambda: any(line["text"] == "still here" for line in tool.status.statustext), 10)
        finally:
            spoofer.close()
            companion.stop()
    link = tool.snapshot()["link"]
    assert link["lost_packets"] == 0 and link["unsigned_sources"] == {"1/100": 40}


def test_camera_heartbeats_from_made_up_ids_are_remembered_16_at_most(surface):
    """Every camera component heard was remembered for the run (65,536 ids possible); now the 16 heard last, until
    the companion is known, and the companion among them is still found."""
    from companion.topside.tool import MAX_CAMERAS

    tool, port = surface
    camera = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    strangers = [Sender(port, 42, 1 + i) for i in range(40)]
    peer = CompanionPeer(port)
    try:
        peer.heartbeat()
        for s in strangers:
            s.send(camera)
        peer.heartbeat()  # heard again: among the newest
        assert wait_until(lambda: tool.status.messages >= 42, 10)
        tool.ctx.requests.put(lambda: None)  # a message is counted before it is handled: let the loop finish it
        assert wait_until(lambda: tool.ctx.requests.empty(), 5)
        assert MAX_CAMERAS == 16 and len(tool._cameras) == 16 and (1, 100) in tool._cameras
        peer.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"started"))
        assert wait_until(lambda: tool.status.companion == (1, 100), 10)
    finally:
        peer.close()
        for s in strangers:
            s.close()
    assert not tool._cameras


def test_pushed_thumbnails_waiting_for_their_crc_keep_the_crc_not_the_bytes(surface):
    """A pushed thumbnail waits for the index.json that lists its CRC: its bytes were kept meanwhile (a push may
    be 2 MiB, one per frame of the summary: gigabytes). Now only its CRC waits."""
    tool, port = surface
    peer = CompanionPeer(port, markers=True)
    peer.tree.remove("/summary/index.json")  # the index never comes: every push waits
    try:
        meet(peer)
        for n in range(20):
            peer.add(summary_frame(n))
        assert wait_until(lambda: tool.status.pushed_ok == 20, 20)
    finally:
        peer.close()
    waiting = tool.ctx.pairing.unverified
    assert sorted(waiting) == list(range(20))
    assert all(isinstance(crc, int) and 0 <= crc < 1 << 32 for crc in waiting.values())


def test_sizes_and_crcs_are_those_of_the_latest_index_only(surface):
    """Each index.json's sizes and CRCs were added to what earlier ones gave, for the whole dive: an index listing
    other made-up frames each pull grew them without end. Now each pull replaces them."""
    tool, port = surface
    peer = CompanionPeer(port)
    frames = [{"image_index": n, "thumbnail": f"summary/{n}.jpg", "thumbnail_bytes": 100, "thumbnail_crc32": n}
              for n in range(1000)]
    peer.tree.put("/summary/index.json", json.dumps({"frames": frames}).encode())
    try:
        meet(peer)
        peer.add(summary_frame(1), push=False)
        assert wait_until(lambda: tool.status.index_pulls == 1, 10)
        frames = [dict(f, image_index=f["image_index"] + 1000) for f in frames]
        peer.tree.put("/summary/index.json", json.dumps({"frames": frames}).encode())
        peer.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"Topics set: fish"))
        assert wait_until(lambda: tool.status.index_pulls == 2 and 1999 in tool.ctx.pairing.crc, 10)
        tool.ctx.requests.put(lambda: None)
        assert wait_until(lambda: tool.ctx.requests.empty(), 5)  # the loop has finished with that index
    finally:
        peer.close()
    assert sorted(tool.ctx.pairing.crc) == list(range(1000, 2000)) and len(tool.ctx.pairing.expected) == 1000


def test_an_index_beyond_what_a_companion_can_hold_is_refused_and_its_strings_are_bounded():
    """index.json (16 MiB at most) could list any number of frames and topics, and strings of any length in each
    capture's topic and file_url, all kept in gallery.json and on the page."""
    from companion.topside.messages import index_topics, parse_index

    many = json.dumps({"frames": [{"image_index": n} for n in range(8193)]}).encode()
    with pytest.raises(ValueError, match="8193 frames, more than 8192"):
        parse_index(many)
    topics = [{"name": f"t{n}", "positive": "fish"} for n in range(9)]
    with pytest.raises(ValueError, match="9 topics, more than 8"):
        index_topics(json.dumps({"topics": topics}).encode())
    with pytest.raises(ValueError, match="not a topic"):
        index_topics(json.dumps({"topics": [{"name": "fish", "positive": "x" * 301}]}).encode())
    with pytest.raises(ValueError, match="not a topic"):
        index_topics(json.dumps({"topics": [{"name": "fish\n", "positive": "fish"}]}).encode())
    [cap] = parse_index(json.dumps({"frames": [{"image_index": 1, "topic": "x" * 100_000,
                                                "file_url": "mftp://summary/" + "y" * 300 + ".jpg"}]}).encode())
    assert cap.topic is None and cap.file_url is None
    [cap] = parse_index(json.dumps({"frames": [{"image_index": 1, "topic": "fish"}]}).encode())
    assert cap.topic == "fish" and cap.file_url is None


def test_pushes_paired_after_they_ended_are_not_remembered_and_pairings_are_bounded(surface):
    """A push before its capture (no marker) waits unpaired, and the capture that then claims it stores it; the
    pairing (handshake -> capture) was remembered all the same, for good: 40 such pushes left 40. Now none, and
    however many are paired while still arriving, 16 at most are kept (``MAX_BOUND``)."""
    from companion.topside.surface_state import MAX_BOUND, PairingState

    tool, port = surface
    peer = CompanionPeer(port)
    peer.tree.remove("/summary/index.json")
    try:
        meet(peer)
        for i in range(40):
            peer.push(bytes([i]) * 600, 20, 20)  # pushed first, then announced
            assert wait_until(lambda i=i: tool.images.completed == i + 1, 10)
            peer.send(_raw_capture(i))
            assert wait_until(lambda i=i: (c := tool.gallery.get(i)) is not None and c.thumbnail is not None, 10)
    finally:
        peer.close()
    assert tool.ctx.pairing.bound == {} and tool.status.pushed_ok == 40
    assert (tool.gallery.root / tool.gallery.get(39).thumbnail).read_bytes() == bytes([39]) * 600

    pairing = PairingState()
    dropped = [pairing.bind(n, 1000 + n) for n in range(1, 41)]
    assert MAX_BOUND == 16 and list(pairing.bound) == list(range(25, 41))
    assert sum(dropped, []) == list(range(1001, 1025))  # the oldest pairings first
