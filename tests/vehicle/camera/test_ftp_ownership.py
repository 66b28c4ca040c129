"""MAVLink FTP with hostile peers, on real UDP: sessions belong to the (signed) link that opened them, strangers
cannot exhaust them, every request is answered, and a restarted client that reuses seq numbers gets fresh bytes
(issue 24 item 4, issue 25 item 1). Raw FTP requests are packed by pymavlink, as an independent client would."""

from __future__ import annotations

import struct

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.conftest import free_udp_port
from tests.vehicle.camera.conftest import serving_frames, signed_companion_link
from tests.vehicle.surface_env import added, companion_link
from tests.vehicle.tether import KEY, Peer, Repeater, gcs_heartbeat
from tests.waiting import wait_until
from vehicle.camera.downlink import Downlink
from vehicle.protocol.ftp import MAX_DATA, FtpErr, FtpPacket, Op
from vehicle.settings import SurfaceConfig

COMPANION = (1, 100)


class RawFtp:
    """A raw FTP client on a ``Peer``: each request waits for the reply carrying its seq + 1."""

    def __init__(self, peer: Peer) -> None:
        self.peer = peer
        self.seq = 0

    def request(self, op: int, *, session: int = 0, offset: int = 0, data: bytes = b"", size: int | None = None,
                seq: int | None = None, timeout: float = 5.0) -> FtpPacket | None:
        seq = self.seq if seq is None else seq
        self.seq = seq + 1
        pkt = FtpPacket(seq, session, op, offset=offset, data=data)
        if size is not None:
            pkt.size_override = size
        self.peer.send(mav2.MAVLink_file_transfer_protocol_message(0, *COMPANION, list(pkt.pack())))

        def replies():
            return [FtpPacket.unpack(m.payload) for m in self.peer.got("FILE_TRANSFER_PROTOCOL", COMPANION)
                    if (m.target_system, m.target_component) == self.peer.ids]

        def match():
            return [r for r in replies() if r.seq == (seq + 1) & 0xFFFF and r.req_opcode == op]

        if not wait_until(lambda: match(), timeout):
            return None
        return match()[-1]

    def download(self, path: str, session: int = 0) -> bytes:
        opened = self.request(Op.OPEN_FILE_RO, session=session, data=path.encode())
        assert opened is not None and opened.opcode == Op.ACK, opened
        size = struct.unpack("<I", opened.data[:4])[0]
        out = b""
        while len(out) < size:
            got = self.request(Op.READ_FILE, session=opened.session, offset=len(out), size=MAX_DATA)
            assert got is not None and got.opcode == Op.ACK, got
            out += got.data
        self.request(Op.TERMINATE_SESSION, session=opened.session)
        return out


@pytest.fixture
def plain():
    """A Downlink without a key holding frames 3, 4 and 5."""
    port = free_udp_port()
    peers: list[Peer] = []
    with serving_frames(companion_link(port)) as surface:
        yield port, surface, peers
    for p in peers:
        p.close()


@pytest.fixture
def signed(tmp_path):
    """The same with a signing key on the companion's link."""
    port = free_udp_port()
    peers: list[Peer] = []
    with serving_frames(signed_companion_link(tmp_path, port)) as surface:
        yield port, surface, peers
    for p in peers:
        p.close()


def _peer(port: int, peers: list[Peer], system: int, component: int, key: bytes | None = None) -> Peer:
    peer = Peer(port, system, component, key)
    peers.append(peer)
    peer.send(gcs_heartbeat())
    return peer


@pytest.mark.slow
def test_a_restarted_client_reusing_seq_numbers_gets_the_new_files_bytes(plain):
    """Issue 25 item 1: download 5.jpg from seq 0, restart (same ids, new socket, seq 0) and download 4.jpg."""
    port, surface, peers = plain
    first = RawFtp(_peer(port, peers, 255, 190))
    assert first.download("/summary/full/5.jpg") == surface.tree.read("/summary/full/5.jpg")
    first.peer.close()
    again = RawFtp(_peer(port, peers, 255, 190))  # same ids, new socket, seq from 0 again
    four = again.download("/summary/full/4.jpg")
    assert four == surface.tree.read("/summary/full/4.jpg")
    assert four != surface.tree.read("/summary/full/5.jpg")[: len(four)]
    # a true retransmission (the very same bytes) is still answered from memory
    before = surface.ftp.retransmits_answered
    listing = again.request(Op.LIST_DIRECTORY, data=b"/summary", seq=40)
    again.request(Op.LIST_DIRECTORY, data=b"/summary", seq=40)
    assert wait_until(lambda: surface.ftp.retransmits_answered == before + 1, 5)
    assert listing.opcode == Op.ACK and b"index.json" in listing.data


def test_eight_spoofed_requesters_cannot_lock_signed_clients_out(signed):
    port, surface, peers = signed
    spoofers = [RawFtp(_peer(port, peers, 255, 200 + i)) for i in range(8)]
    held = [s.request(Op.OPEN_FILE_RO, data=b"/summary/index.json") for s in spoofers]
    assert all(h is not None for h in held)  # every request is answered (ACK or NAK), never silence
    clients = [RawFtp(_peer(port, peers, 255, 190 + i, KEY)) for i in range(3)]
    granted = [c.request(Op.OPEN_FILE_RO, data=b"/summary/full/4.jpg") for c in clients]
    available = sum(g is not None and g.opcode == Op.ACK for g in granted)
    print(f"\nsigned clients granted a session under 8 spoofed requesters: {available}/3 "
          f"(spoofers hold {sum(h.opcode == Op.ACK for h in held)} of 8 granted)")
    assert available == 3
    assert clients[0].download("/summary/full/3.jpg", session=1) == surface.tree.read("/summary/full/3.jpg")


def test_a_spoofed_request_on_a_signed_session_is_refused_and_the_owner_is_unharmed(signed):
    port, surface, peers = signed
    owner = RawFtp(_peer(port, peers, 255, 190, KEY))
    spoof = RawFtp(_peer(port, peers, 255, 190))  # the owner's ids, no key
    spoof.seq = 100
    index = surface.tree.read("/summary/index.json")
    opened = owner.request(Op.OPEN_FILE_RO, data=b"/summary/index.json")
    assert opened.opcode == Op.ACK
    first = owner.request(Op.READ_FILE, session=opened.session, offset=0, size=MAX_DATA)
    # the stranger tries to re-open the owner's session on another file, to read it, and to end it
    hijack = spoof.request(Op.OPEN_FILE_RO, session=opened.session, data=b"/summary/full/5.jpg")
    read = spoof.request(Op.READ_FILE, session=opened.session, offset=0, size=MAX_DATA)
    end = spoof.request(Op.TERMINATE_SESSION, session=opened.session)
    assert [(r.opcode, r.data[:1]) for r in (hijack, read)] == [(Op.NAK, bytes([FtpErr.FAIL]))] * 2
    assert (end.opcode, end.data[:1]) == (Op.NAK, bytes([FtpErr.FAIL]))  # not its session: refused, answered
    out = first.data
    while len(out) < len(index):
        got = owner.request(Op.READ_FILE, session=opened.session, offset=len(out), size=MAX_DATA)
        assert got.opcode == Op.ACK
        out += got.data
    assert out == index  # the rest of index.json, not JPEG bytes
    assert owner.request(Op.TERMINATE_SESSION, session=opened.session).opcode == Op.ACK
    assert surface.ftp.sessions.refused_foreign >= 2


def test_a_signed_upload_survives_a_spoofed_write_on_its_session(signed):
    port, surface, peers = signed
    changed = []
    surface.on_queries_changed(lambda topics: changed.append(topics[0].positive))
    owner = RawFtp(_peer(port, peers, 255, 190, KEY))
    spoof = RawFtp(_peer(port, peers, 255, 190))
    spoof.seq = 100
    made = owner.request(Op.CREATE_FILE, data=b"/config/queries.txt")
    assert made.opcode == Op.ACK
    text = b"a coral reef\nsand\n"
    assert owner.request(Op.WRITE_FILE, session=made.session, data=text).opcode == Op.ACK
    bad = spoof.request(Op.WRITE_FILE, session=made.session, data=b"a diver\nsand\n")
    assert bad.opcode == Op.NAK
    assert owner.request(Op.TERMINATE_SESSION, session=made.session).opcode == Op.ACK
    assert changed == ["a coral reef"]


def test_an_unsigned_client_ends_its_own_read_sessions_and_no_one_elses(signed):
    """Issue 46 item 3: with a key, an unsigned ground station's TerminateSession and ResetSessions end its own
    read sessions (they were refused as protected); a signed client's session with the same ids is untouched."""
    port, surface, peers = signed
    owner = RawFtp(_peer(port, peers, 255, 190, KEY))
    plain = RawFtp(_peer(port, peers, 255, 190))  # the owner's ids, no key: its own sessions are unsigned ones
    plain.seq = 100
    held = owner.request(Op.OPEN_FILE_RO, session=3, data=b"/summary/index.json")
    assert held.opcode == Op.ACK
    opened = plain.request(Op.OPEN_FILE_RO, session=1, data=b"/summary/full/3.jpg")
    assert opened.opcode == Op.ACK
    assert plain.request(Op.READ_FILE, session=1, size=MAX_DATA).opcode == Op.ACK
    assert plain.request(Op.TERMINATE_SESSION, session=1).opcode == Op.ACK
    gone = plain.request(Op.READ_FILE, session=1, size=MAX_DATA)
    assert (gone.opcode, gone.data[:1]) == (Op.NAK, bytes([FtpErr.INVALID_SESSION]))
    for number in (1, 2):  # two read sessions, both ended by one ResetSessions
        assert plain.request(Op.OPEN_FILE_RO, session=number, data=b"/summary/index.json").opcode == Op.ACK
    assert plain.request(Op.RESET_SESSIONS).opcode == Op.ACK
    for number in (1, 2):
        after = plain.request(Op.READ_FILE, session=number, size=MAX_DATA)
        assert (after.opcode, after.data[:1]) == (Op.NAK, bytes([FtpErr.INVALID_SESSION]))
    end = plain.request(Op.TERMINATE_SESSION, session=3)  # the signed client's session: not its own
    assert (end.opcode, end.data[:1]) == (Op.NAK, bytes([FtpErr.FAIL]))
    read = owner.request(Op.READ_FILE, session=3, size=MAX_DATA)  # the reset and the refused end left it open
    assert read.opcode == Op.ACK and read.data == surface.tree.read("/summary/index.json")[:MAX_DATA]
    assert surface.ftp.naks.get(int(FtpErr.FILE_PROTECTED), 0) == 0  # no end of a session refused as protected


def test_a_strangers_endless_bursts_never_hold_back_a_signed_clients_reads(tmp_path):
    """Issue 46 review: on the default 2000 B/s downlink an unsigned client restarting a burst read four times a
    second keeps a burst always running; the signed client's READ_FILE answers (FTP data, the same bulk priority)
    still go out, as they went first before its burst (an unsigned burst drew on no slice and went ahead of them)."""
    port = free_udp_port()
    link = signed_companion_link(tmp_path, port)
    surface = Downlink(link, SurfaceConfig(push=False))
    peers: list[Peer] = []
    flood = None
    try:
        surface.start()
        for i in (3, 4, 5):
            surface.publish(added(i, [3, 4, 5][: i - 2]))
        stranger = RawFtp(_peer(port, peers, 255, 191))
        opened = stranger.request(Op.OPEN_FILE_RO, session=1, data=b"/summary/full/5.jpg", timeout=20)
        assert opened is not None and opened.opcode == Op.ACK
        burst = FtpPacket(50, 1, Op.BURST_READ_FILE, offset=0).pack()
        flood = Repeater(stranger.peer, lambda: [mav2.MAVLink_file_transfer_protocol_message(0, *COMPANION,
                                                                                              list(burst))], 4)

        def burst_packets() -> int:
            return sum(FtpPacket.unpack(m.payload).req_opcode == Op.BURST_READ_FILE
                       for m in stranger.peer.got("FILE_TRANSFER_PROTOCOL", COMPANION))

        assert wait_until(lambda: burst_packets() >= 3, 20), "the stranger's burst never ran"
        owner = RawFtp(_peer(port, peers, 255, 190, KEY))
        held = owner.request(Op.OPEN_FILE_RO, session=2, data=b"/summary/full/4.jpg", timeout=20)
        assert held is not None and held.opcode == Op.ACK
        want = surface.tree.read("/summary/full/4.jpg")
        for offset in (0, MAX_DATA, 2 * MAX_DATA):
            read = owner.request(Op.READ_FILE, session=2, offset=offset, size=MAX_DATA, timeout=15)
            assert read is not None, f"the signed read at {offset} was never answered during the stranger's bursts"
            assert read.opcode == Op.ACK and read.data == want[offset:offset + MAX_DATA]
        before = burst_packets()
        assert wait_until(lambda: burst_packets() > before, 20), "the stranger's bursts stopped altogether"
    finally:
        if flood is not None:
            flood.stop()
        surface.stop()
        link.stop()
        for p in peers:
            p.close()
