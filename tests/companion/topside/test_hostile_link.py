"""The surface tool against a hostile device on the tether: real UDP sockets on 127.0.0.1, real pymavlink messages,
the real FTP server answering. Each test is an attack an earlier helper found, and what the tool must do instead."""

from __future__ import annotations

import csv
import json
import socket
import threading
import time
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.topside.ftp_client import MAX_FILE_BYTES, FtpClient
from companion.topside.gallery import Gallery
from companion.topside.tool import SurfaceOptions, SurfaceTool
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.camera.captures import captured_message
from vehicle.camera.ftp_server import FtpServer, VirtualTree
from vehicle.camera.status import push_marker
from vehicle.protocol.ftp import MAX_DATA, FtpErr, FtpPacket, Op, ack, nak
from vehicle.protocol.image_push import CHUNK, MAX_PUSH_BYTES, ImageReceiver


@contextmanager
def running_tool(folder: Path, gallery: Gallery | None = None, **options) -> Iterator[tuple[SurfaceTool, int]]:
    """A surface tool listening on a free UDP port, its receive loop on a thread; yields (tool, port)."""
    port = free_udp_port()
    tool = SurfaceTool(SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", index_refresh_s=0.5, **options),
                       gallery or Gallery(folder))
    tool.open()
    stop = threading.Event()
    thread = threading.Thread(target=tool.run, args=(stop,), daemon=True)
    thread.start()
    try:
        yield tool, port
    finally:
        stop.set()
        thread.join(10)
    assert not thread.is_alive()


@pytest.fixture
def surface(tmp_path):
    with running_tool(tmp_path / "gallery") as running:
        yield running


class Scripted:
    """A hostile FTP server: answers each request as ``answer`` says (the real one is ``FtpServer``)."""

    def __init__(self, answer: Callable[[FtpPacket], list[FtpPacket]]) -> None:
        self.answer = answer

    def handle(self, payload: bytes, _requester) -> list[bytes]:
        return [reply.pack() for reply in self.answer(FtpPacket.unpack(payload))]

    def next_burst(self) -> None:
        return None


class FtpFarSide:
    """A MAVLink FTP server on a real UDP socket (as system 1/100), answering whoever asks at their address."""

    def __init__(self, server: FtpServer | Scripted) -> None:
        self.server = server
        self.requests: list[FtpPacket] = []
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self._mav = mav.MAVLink(None, srcSystem=1, srcComponent=100)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        parser = mav.MAVLink(None)
        while not self._stop.is_set():
            try:
                data, who = self.sock.recvfrom(4096)
            except TimeoutError:
                continue
            for msg in parser.parse_buffer(data) or []:
                self.requests.append(FtpPacket.unpack(msg.payload))
                requester = (msg.get_srcSystem(), msg.get_srcComponent())
                replies = [(requester, r) for r in self.server.handle(bytes(msg.payload), requester)]
                while (burst := self.server.next_burst()) is not None:
                    replies.append(burst)
                for (system, component), reply in replies:
                    out = mav.MAVLink_file_transfer_protocol_message(0, system, component, list(reply))
                    self.sock.sendto(out.pack(self._mav), who)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


class ClientSide:
    """Our FTP client on its own real UDP socket, talking to the server at ``port``; the test pumps it, and may
    hold back what it sends (``hold``) to interleave two clients exactly."""

    def __init__(self, port: int, **client_options) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.port = port
        self._packer, self._parser = mav.MAVLink(None, srcSystem=254, srcComponent=190), mav.MAVLink(None)
        self.hold = False
        self.held: list[bytes] = []
        self.client = FtpClient(self._send, (1, 100), own=(254, 190), **client_options)
        self.outcomes: list[tuple[bytes | None, str]] = []

    def _send(self, system: int, component: int, payload: bytes) -> None:
        packet = mav.MAVLink_file_transfer_protocol_message(0, system, component, list(payload)).pack(self._packer)
        if self.hold:
            self.held.append(packet)
        else:
            self.sock.sendto(packet, ("127.0.0.1", self.port))

    def fetch(self, path: str) -> None:
        self.client.fetch(path, lambda _p, data, error: self.outcomes.append((data, error)))

    def release(self) -> None:
        self.hold = False
        for packet in self.held:
            self.sock.sendto(packet, ("127.0.0.1", self.port))
        self.held.clear()

    def pump(self, until: Callable[[], bool], timeout: float = 30.0) -> None:
        end = time.monotonic() + timeout
        while not until() and time.monotonic() < end:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                data = b""
            for msg in self._parser.parse_buffer(data) or []:
                self.client.handle(msg)
            self.client.tick()
        assert until(), "the client never got there"

    def close(self) -> None:
        self.sock.close()


def fetch_from(server: FtpFarSide, path: str, **client_options) -> tuple[bytes | None, str]:
    """Our FTP client reading ``path`` from ``server``; (data or None, error)."""
    side = ClientSide(server.port, **client_options)
    try:
        side.fetch(path)
        side.pump(lambda: bool(side.outcomes))
    finally:
        side.close()
    return side.outcomes[0]


def meet(peer: CompanionPeer) -> None:
    """Say hello until the tool answers (a udpin link learns where to send from what it receives)."""
    assert wait_until(lambda: peer.heartbeat() or any(m.get_type() == "HEARTBEAT" for m in peer.received), 10)


def test_a_dive_id_that_is_not_a_safe_name_puts_nothing_outside_the_gallery(surface, tmp_path):
    tool, port = surface
    outside = tmp_path / "outside"
    peer = CompanionPeer(port)
    # index.json names a dive that is a path: before, a full frame the page asked for was written at outside/1.jpg
    peer.tree.put("/summary/index.json", json.dumps({"dive": str(outside), "frames": [{"image_index": 1}]}).encode())
    peer.tree.put("/summary/full/1.jpg", b"\xff\xd8full frame\xff\xd9")
    try:
        meet(peer)
        peer.add(summary_frame(1))
        assert wait_until(lambda: tool.ctx.ftp is not None and tool.ctx.ftp.files_done >= 1, 10)  # the index came
        full = tool.full_frame(1, timeout=10)
        peer.send(captured_message(summary_frame(2), 0))
        peer.send(captured_message(summary_frame(7), 0, dive=".."))  # a capture in the folder above the dives
        peer.send(captured_message(summary_frame(3), 0))
        assert wait_until(lambda: tool.gallery.get(3) is not None, 10)
    finally:
        peer.close()
    assert not outside.exists()
    assert full == tmp_path / "gallery" / "full" / "unknown" / "1.jpg" and full.read_bytes().startswith(b"\xff\xd8")
    assert tool.gallery.dive is None and tool.gallery.dives() == []
    assert tool.gallery.get(7) is None  # ignored, with a log line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gallery"]


def test_an_ftp_file_over_16_mib_is_refused_before_a_byte_is_read():
    """The open's ACK says 64 MiB (a hostile server could say 4 GiB): before, the client allocated buffers of that
    size and asked for the file; now it closes the session at once and says why."""

    def answer(request: FtpPacket) -> list[FtpPacket]:
        if request.opcode == Op.OPEN_FILE_RO:
            return [ack(request, data=(64 << 20).to_bytes(4, "little"))]
        if request.opcode == Op.TERMINATE_SESSION:
            return [ack(request)]
        return [nak(request, FtpErr.FAIL)]

    server = FtpFarSide(Scripted(answer))
    try:
        data, error = fetch_from(server, "/summary/index.json")
    finally:
        server.close()
    assert data is None and error == f"file of {64 << 20} bytes refused: over the 16 MiB cap"
    assert [r.opcode for r in server.requests] == [Op.OPEN_FILE_RO, Op.TERMINATE_SESSION]  # nothing read
    assert MAX_FILE_BYTES == 16 << 20


def test_a_file_of_unknown_size_that_never_ends_is_cut_at_the_cap():
    """An open ACK of size 0 means "read to the end": a server that never says EOF is cut at the cap."""

    def answer(request: FtpPacket) -> list[FtpPacket]:
        if request.opcode == Op.OPEN_FILE_RO:
            return [ack(request, data=(0).to_bytes(4, "little"))]
        if request.opcode == Op.READ_FILE:
            return [ack(request, data=b"x" * MAX_DATA)]
        return [ack(request)]

    server = FtpFarSide(Scripted(answer))
    try:
        data, error = fetch_from(server, "/summary/index.json", max_file_bytes=20 * MAX_DATA)
    finally:
        server.close()
    assert data is None and error == f"file refused: over the {20 * MAX_DATA}-byte cap at offset {20 * MAX_DATA}"
    reads = [r for r in server.requests if r.opcode == Op.READ_FILE]
    assert len(reads) == 21 and server.requests[-1].opcode == Op.TERMINATE_SESSION


def test_pushes_no_capture_claims_are_kept_16_at_most(surface):
    """Before, every pushed image nobody announced stayed in memory for the whole run (40 here, 1,000 as easily)."""
    tool, port = surface
    peer = CompanionPeer(port)
    try:
        meet(peer)
        for i in range(40):
            peer.push(bytes([i]) * 600, 20, 20)  # three packets each, never announced
        assert wait_until(lambda: tool.images.completed == 40, 10)
        assert wait_until(lambda: tool.status.unpaired_dropped == 24, 5)
    finally:
        peer.close()
    assert sorted(tool.ctx.pairing.orphans) == list(range(25, 41))  # the newest 16, by handshake number
    assert tool.snapshot()["link"]["unpaired_dropped"] == 24


class Sender:
    """A pymavlink packer with its own ids on its own UDP socket, sending to the tool."""

    def __init__(self, port: int, system: int, component: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.mav = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        self.to = ("127.0.0.1", port)

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.to)
        self.mav.seq = (self.mav.seq + 1) % 256

    def close(self) -> None:
        self.sock.close()


def autopilot_heartbeat() -> mav.MAVLink_heartbeat_message:
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)


def test_a_stranger_claiming_to_be_an_autopilot_does_not_replace_the_first(surface):
    tool, port = surface
    vehicle, stranger = Sender(port, 1, 1), Sender(port, 42, 1)
    try:
        vehicle.send(autopilot_heartbeat())
        assert wait_until(lambda: tool.snapshot()["link"]["autopilot"] == [1, 1], 10)
        for _ in range(5):
            stranger.send(autopilot_heartbeat())
        assert wait_until(lambda: tool.status.foreign_autopilot_heartbeats == 5, 10)
    finally:
        vehicle.close()
        stranger.close()
    link = tool.snapshot()["link"]
    assert link["autopilot"] == [1, 1] and link["foreign_autopilot_heartbeats"] == 5


def test_values_under_made_up_names_are_shown_64_at_most(surface):
    tool, port = surface
    peer = CompanionPeer(port)
    try:
        meet(peer)
        peer.add(summary_frame(1))  # the companion is known: its values are shown
        peer.values(MRL_DEPTH=12.5)
        for i in range(100):
            peer.send(mav.MAVLink_named_value_float_message(0, f"X{i}".encode(), float(i)))
        peer.values(MRL_DEPTH=13.0)  # a name already shown is still updated
        assert wait_until(lambda: tool.snapshot()["companion"]["values"].get("MRL_DEPTH") == 13.0, 10)
    finally:
        peer.close()
    values = tool.snapshot()["companion"]["values"]
    assert len(values) == 64 and "X62" in values and "X63" not in values
    assert tool.snapshot()["link"]["values_dropped"] == 37


def test_a_flood_while_the_loop_is_held_up_is_dropped_at_the_inbox_not_queued(surface):
    """The loop held up (here by a request that waits, as a slow disk would): 10,000 messages arrive, 4,096 wait,
    the rest are counted; once free, the loop answers again."""
    from companion.topside.tool import INBOX_MAX

    tool, port = surface
    held, release = threading.Event(), threading.Event()
    tool.ctx.requests.put(lambda: held.set() or release.wait(30))
    assert held.wait(10)
    flood = Sender(port, 42, 1)
    try:
        beat = autopilot_heartbeat()
        for _ in range(250):
            flood.sock.sendto(b"".join(beat.pack(flood.mav) for _ in range(40)), flood.to)  # 40 to a datagram
            time.sleep(0.001)
        assert wait_until(lambda: tool.status.inbox_dropped + tool._inbox.qsize() == 10_000, 20)
        assert tool._inbox.qsize() == INBOX_MAX and tool.status.inbox_dropped == 10_000 - INBOX_MAX
    finally:
        release.set()
        flood.close()
    assert wait_until(lambda: tool._inbox.qsize() == 0, 20)
    assert tool.full_frame(1, timeout=10) is None  # the loop answers the page again (no companion: nothing to fetch)


def test_status_lines_before_the_companion_are_kept_for_16_sources_at_most(surface):
    tool, port = surface
    senders = [Sender(port, 100 + i, 100) for i in range(40)]
    try:
        for s in senders:
            s.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"started"))
        assert wait_until(lambda: tool.status.messages == 40, 10)
    finally:
        for s in senders:
            s.close()
    assert sorted(tool._early_text) == [(100 + i, 100) for i in range(24, 40)]


def _two_tools_with_the_same_ids(sessions: tuple[int | None, int | None]) -> tuple[bytes | None, str]:
    """Tool A opens /a; tool B (same ids 254/190, its own socket) then reads /b whole; then A reads. A's outcome."""
    tree = VirtualTree()
    tree.put("/a", b"A" * 3000)
    tree.put("/b", b"B" * 2000)
    server = FtpFarSide(FtpServer(tree))  # the companion's own FTP server
    port = server.port
    a, b = ClientSide(port, session=sessions[0]), ClientSide(port, session=sessions[1])
    try:
        a.fetch("/a")
        a.hold = True  # what A sends after its open waits
        a.pump(lambda: bool(a.held))  # A's open is granted; its first read is held back
        b.fetch("/b")
        b.pump(lambda: bool(b.outcomes))
        assert b.outcomes == [(b"B" * 2000, "")]
        a.release()
        a.pump(lambda: bool(a.outcomes))
    finally:
        a.close()
        b.close()
        server.close()
    return a.outcomes[0]


def test_each_tool_opens_ftp_sessions_under_its_own_random_number():
    """Every client asked for session 0, and a server keeps sessions per sender ids: a second tool with the same
    ids (another ``merlion surface``, ``surface-mark``) replaced and closed the first one's open file."""
    assert _two_tools_with_the_same_ids((0, 0))[0] is None  # what any two tools did: A's download failed
    assert _two_tools_with_the_same_ids((17, 201)) == (b"A" * 3000, "")
    sessions = {FtpClient(lambda *_: None, (1, 100)).session for _ in range(20)}
    assert len(sessions) > 1 and all(0 <= n < 256 for n in sessions)  # all 20 alike: one chance in 256**19


def test_a_flood_of_captures_rewrites_gallery_json_4_times_a_second_at_most(surface, tmp_path):
    """Each gallery.json rewrite is the whole file, fsynced: before, 600 captures sent as fast as they go cost
    600 rewrites (each longer than the last); now at most one per 0.25 s, and the run ends with the last state."""
    tool, port = surface
    peer = CompanionPeer(port)
    try:
        meet(peer)
        started = time.monotonic()
        for i in range(600):
            peer.send(captured_message(summary_frame(i), 0))
        assert wait_until(lambda: tool.gallery.get(599) is not None, 30)
        elapsed = time.monotonic() - started
    finally:
        peer.close()
    assert tool.gallery.json_writes <= 2 + elapsed / 0.25
    assert wait_until(lambda: len(Gallery(tmp_path / "gallery").captures()) == 600, 5)  # flushed by the loop


def _big_push(size: int, packets: int = 3) -> list:
    """The handshake of a ``size``-byte JPEG push and its first ``packets`` packets."""
    count = (size + CHUNK - 1) // CHUNK
    return [mav.MAVLink_data_transmission_handshake_message(0, size, 4000, 3000, count, CHUNK, 80),
            *(mav.MAVLink_encapsulated_data_message(n, [n & 0xFF] * CHUNK) for n in range(packets))]


def test_a_push_over_2_mib_is_never_assembled_and_its_frame_comes_by_ftp(tmp_path):
    """A handshake announcing 3 MiB: before, a buffer of that size waited for packets until the push stalled (60 s
    here); now nothing is allocated and the frame the marker names is fetched by FTP at once."""
    with running_tool(tmp_path / "gallery", push_stall_s=60.0) as (tool, port):
        peer = CompanionPeer(port)
        try:
            meet(peer)
            thumbnail = peer.add(summary_frame(1), push=False)  # announced; its thumbnail is served by FTP
            peer.send(push_marker(1, 0))
            for msg in _big_push(3 << 20):
                peer.send(msg)
            # the capture itself may not be filed yet when the waiting starts
            assert wait_until(lambda: (frame := tool.gallery.get(1)) is not None and frame.thumbnail is not None, 10)
        finally:
            peer.close()
    one = tool.gallery.get(1)
    assert one.thumbnail_via == "ftp" and (tmp_path / "gallery" / one.thumbnail).read_bytes() == thumbnail
    assert (tool.images.oversized, tool.images.completed, tool.status.pushed_lost) == (1, 0, 1)


def test_the_image_receiver_allocates_nothing_for_a_push_over_the_cap():
    packer, parser = mav.MAVLink(None, srcSystem=1, srcComponent=100), mav.MAVLink(None)

    def peak(size: int) -> tuple[int, object]:
        receiver = ImageReceiver()
        messages = [parser.decode(bytearray(m.pack(packer))) for m in _big_push(size)]
        tracemalloc.start()
        try:
            for m in messages:
                assert receiver.handle(m) is None
            return tracemalloc.get_traced_memory()[1], receiver.take_oversized((1, 100))
        finally:
            tracemalloc.stop()

    allowed, gone = peak(MAX_PUSH_BYTES)
    assert allowed >= MAX_PUSH_BYTES and gone is None  # what a push at the cap costs, and it is assembled
    refused, gone = peak(MAX_PUSH_BYTES + 1)
    assert refused < 64 * 1024
    assert gone.oversized and (gone.handshake_no, gone.received_packets, gone.chunks) == (1, 0, {})


@pytest.mark.parametrize("index", [b'{"frames": [{"image_index": 1e400}]}', b'{"frames": [{"image_index": [1]}]}',
                                   b'{"frames": [{"index": 2, "q": [[1], 0, 0, 0]}]}', b'{"frames": {"4": 5}}'])
def test_an_index_with_values_of_the_wrong_kind_is_one_log_line(surface, caplog, index):
    tool, port = surface
    peer = CompanionPeer(port)
    peer.tree.put("/summary/index.json", index)
    try:
        meet(peer)
        peer.add(summary_frame(1), push=False)

        def ignored() -> list:
            return [r for r in caplog.records if "/summary/index.json ignored" in r.getMessage()]

        assert wait_until(lambda: ignored() or [r for r in caplog.records if r.exc_info], 10)
    finally:
        peer.close()
    assert len(ignored()) == 1 and ignored()[0].levelname == "WARNING"
    assert not [r for r in caplog.records if r.exc_info]  # no traceback
    assert tool.status.index_pulls == 0 and [c.image_index for c in tool.gallery.summary()] == [1]


def test_made_up_sequence_numbers_from_made_up_ids_neither_grow_the_table_nor_count_as_lost(surface):
    """Before, every (system, component) heard got a row in the sequence table (65,536 possible) and its jumps
    were counted in ``lost_packets``: 300 strangers jumping 100 each made 29,700 "lost" packets. Now only the
    vehicle's own sources (the autopilot and the companion) are followed."""
    tool, port = surface
    vehicle = Sender(port, 1, 1)
    strangers = [Sender(port, 100 + i // 3, 10 + i % 3) for i in range(300)]
    try:
        vehicle.send(autopilot_heartbeat())
        assert wait_until(lambda: tool.snapshot()["link"]["autopilot"] == [1, 1], 10)
        gcs = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
        for s in strangers:
            s.send(gcs)
            s.mav.seq = 101  # 100 made-up "lost" packets
            s.send(gcs)
        vehicle.mav.seq = 5  # the autopilot's own losses still count: four
        vehicle.send(autopilot_heartbeat())
        assert wait_until(lambda: tool.status.messages == 602, 10)
    finally:
        vehicle.close()
        for s in strangers:
            s.close()
    assert tool.snapshot()["link"]["lost_packets"] == 4
    assert set(tool._last_seq) == {(1, 1)}


def test_captures_jumping_ahead_ask_again_for_16_lost_captures_and_then_one_a_second(surface):
    """Each capture whose index jumps ahead asks again for the captures in between (up to 16): before, 50 captures
    jumping 20 each made the tool send 784 MAV_CMD_REQUEST_MESSAGE. Now one bucket bounds them all."""
    tool, port = surface
    peer = CompanionPeer(port)

    def requests() -> int:
        return sum(1 for m in list(peer.received) if m.get_type() == "COMMAND_LONG"
                   and m.command == mav.MAV_CMD_REQUEST_MESSAGE)

    try:
        meet(peer)
        started = time.monotonic()
        for i in range(50):
            peer.send(captured_message(summary_frame(20 * i), 0))
        assert wait_until(lambda: tool.gallery.get(980) is not None, 20)
        assert wait_until(lambda: requests() >= 16, 5)
        # capture 980 is filed before the 16 it skipped are asked for (or refused), and what the tool sent may still
        # be on its way to the peer: wait until each of the 784 asks was received or refused
        assert wait_until(lambda: requests() + tool.status.requests_refused == 784, 5)
        elapsed = time.monotonic() - started
        sent = requests()
    finally:
        peer.close()
    assert sent <= 16 + elapsed / 1.0 + 1
    assert tool.status.requests_refused == 784 - sent
    assert tool.snapshot()["link"]["requests_refused"] == 784 - sent
    assert len(tool.gallery.captures()) == 50 + 784  # the lost ones are still expected, asked for or not


def _paced(tool: SurfaceTool, peer: CompanionPeer, messages: list, batch: int = 500) -> None:
    """Send ``messages`` as the companion, a batch at a time, each handled before the next (nothing dropped at the
    inbox: what is measured is what the gallery keeps)."""
    for start in range(0, len(messages), batch):
        target = tool.status.messages + len(messages[start:start + batch])
        for msg in messages[start:start + batch]:
            peer.send(msg)
        assert wait_until(lambda target=target: tool.status.messages >= target, 30)
    assert tool.status.inbox_dropped == 0


def test_frames_trimmed_out_are_kept_4096_per_dive_the_first_trimmed_forgotten_first(surface, tmp_path, caplog):
    """``Summary -#n`` for any n added a trimmed frame for the whole run (before: 5,000 trims, 5,000 kept, each
    rewrite of gallery.json longer). Now the newest 4,096 trims are kept; the summary's frames always."""
    from companion.topside.gallery import MAX_HISTORY

    tool, port = surface
    peer = CompanionPeer(port)
    try:
        meet(peer)
        peer.add(summary_frame(1))
        peer.add(summary_frame(2))
        assert wait_until(lambda: all(tool.gallery.get(i) and tool.gallery.get(i).thumbnail for i in (1, 2)), 10)
        peer.trim(1)
        assert wait_until(lambda: not tool.gallery.get(1).in_summary, 10)
        assert (tmp_path / "gallery" / "removed" / "1.jpg").exists()
        trims = [mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, f"Summary -#{n}".encode())
                 for n in range(1000, 6000)]
        _paced(tool, peer, trims)
    finally:
        peer.close()
    state = tool.snapshot()
    assert MAX_HISTORY == 4096 and state["history_dropped"] == 5001 - 4096
    assert [c["image_index"] for c in state["summary"]] == [2] and tool.gallery.get(2).thumbnail == "summary/2.jpg"
    kept = [c.image_index for c in tool.gallery.captures() if not c.in_summary]
    assert sorted(kept) == list(range(6000 - 4096, 6000))  # frame 1 and the first 904 trims went, first first
    assert not (tmp_path / "gallery" / "removed" / "1.jpg").exists()
    assert len([r for r in caplog.records if "forgotten" in r.getMessage()]) == 1
    tool.gallery.flush()
    again = Gallery(tmp_path / "gallery")
    assert len(again.captures()) == 4097 and again.history_dropped == 905


def _raw_capture(index: int) -> mav.MAVLink_camera_image_captured_message:
    return mav.MAVLink_camera_image_captured_message(0, 0, 0, 0, 0, 0, -12500, [1, 0, 0, 0], index, 1, b"")


def test_a_summary_announced_without_end_keeps_8192_frames_the_first_announced_leaving_first(surface):
    """Captures announced and never trimmed (a sender that serves no index.json to mirror) were all the summary.
    Past 8,192 (a companion holds 8 topics of 1,000 at most) the first announced leaves it, as if trimmed."""
    from companion.topside.gallery import MAX_SUMMARY

    tool, port = surface
    peer = CompanionPeer(port)
    peer.tree.remove("/summary/index.json")  # nothing to mirror: every capture stays in the summary
    try:
        meet(peer)
        _paced(tool, peer, [_raw_capture(n) for n in range(MAX_SUMMARY + 100)])
    finally:
        peer.close()
    summary = [c.image_index for c in tool.gallery.summary()]
    assert MAX_SUMMARY == 8192 and sorted(summary) == list(range(100, MAX_SUMMARY + 100))
    assert sorted(c.image_index for c in tool.gallery.captures() if not c.in_summary) == list(range(100))


def test_log_csv_gets_a_bounded_number_of_rows_per_run(tmp_path):
    """Each event was a row for the whole run. Now a run writes ``max_log_rows`` (100,000 by default, about 10 MB;
    1,000 here), then one ``log_full`` row; the next run appends again."""
    from companion.topside.gallery import MAX_LOG_ROWS

    folder = tmp_path / "gallery"
    with running_tool(folder, Gallery(folder, max_log_rows=1000)) as (tool, port):
        peer = CompanionPeer(port)
        try:
            meet(peer)
            _paced(tool, peer, [mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, f"Summary -#{n}".encode())
                                for n in range(1500)])
        finally:
            peer.close()
    with (folder / "log.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1001 and rows[-1]["event"] == "log_full" and rows[-2]["image_index"] == "999"
    assert tool.snapshot()["log_rows_dropped"] == 500 and MAX_LOG_ROWS == 100_000
    assert len(Gallery(folder).captures()) == 1500  # the state is all in gallery.json
    Gallery(folder, max_log_rows=1000).remove(5000)  # a new run
    with (folder / "log.csv").open(newline="", encoding="utf-8") as fh:
        assert list(csv.DictReader(fh))[-1]["image_index"] == "5000"
