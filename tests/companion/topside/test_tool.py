"""The surface tool end to end in-process: captures paired with pushes, FTP fallback, trims mirrored."""

from __future__ import annotations

import random
import threading

import pytest

from companion.commands.surface import serve
from companion.topside.gallery import Gallery
from companion.topside.tool import SurfaceOptions
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.camera.thumbnails import make_thumbnail


def test_gallery_mirrors_the_companion_summary_with_push_and_ftp_fallback(tmp_path):
    port = free_udp_port()
    stop = threading.Event()
    options = SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", push_timeout_s=3.0, index_refresh_s=0.5)
    thread = threading.Thread(target=serve, args=(options, str(tmp_path)), kwargs={"stop": stop}, daemon=True)
    thread.start()
    peer = CompanionPeer(port)
    try:
        gallery = Gallery(tmp_path)  # a second reader of the same folder: what the tool wrote is on disk
        # until the tool answers (its heartbeat), it may not be listening yet
        assert wait_until(lambda: peer.heartbeat() or any(m.get_type() == "HEARTBEAT" for m in peer.received), 10)
        sent = {}
        sent[1] = peer.add(summary_frame(1, depth=10.0, yaw_deg=30, score=0.91))
        sent[2] = peer.add(summary_frame(2, depth=11.0, yaw_deg=60, score=0.82), drop_chunks={2})  # stalls
        sent[3] = peer.add(summary_frame(3, depth=12.0, yaw_deg=90, score=0.73))
        sent[4] = peer.add(summary_frame(4, depth=13.0, yaw_deg=120, score=0.64), drop_chunks={-1})  # no handshake
        sent[5] = peer.add(summary_frame(5, depth=14.0, yaw_deg=150, score=0.55), announce=False)  # capture lost
        sent[6] = peer.add(summary_frame(6, depth=15.0, yaw_deg=180, score=0.46))
        sent[7] = peer.add(summary_frame(7, depth=16.0, yaw_deg=210, score=0.37), push=False)  # push never comes
        peer.values(MRL_FPS=4.5, MRL_SUMN=4)
        peer.trim(3)

        def settled() -> bool:
            g = Gallery(tmp_path)
            held = {c.image_index: c for c in g.summary()}
            return set(held) == {1, 2, 4, 5, 6, 7} and all(c.thumbnail and c.score is not None and c.depth_m
                                                        for c in held.values())

        assert wait_until(settled, 30), Gallery(tmp_path).captures()
        gallery = Gallery(tmp_path)
        held = {c.image_index: c for c in gallery.summary()}
        for i in (1, 2, 4, 5, 6, 7):
            assert (tmp_path / held[i].thumbnail).read_bytes() == sent[i], (i, held[i])
        assert held[1].thumbnail_via == "push"
        assert held[2].thumbnail_via == "push+ftp"  # the stalled push's packets, the lost one pulled by FTP
        assert held[4].thumbnail_via == "ftp" and held[7].thumbnail_via == "ftp"
        assert (held[1].depth_m, held[1].score) == (10.0, 0.91)
        assert abs(held[4].heading_deg - 120) < 0.2
        assert held[5].thumbnail_via == "push" and held[6].thumbnail_via == "push"  # pushes kept their order
        assert held[5].depth_m == 14.0  # the lost capture was asked for again (MAV_CMD_REQUEST_MESSAGE)
        assert any(m.get_type() == "COMMAND_LONG" and m.param2 == 5 for m in peer.received)
        three = gallery.get(3)
        assert not three.in_summary and (tmp_path / "removed" / "3.jpg").read_bytes() == sent[3]
    finally:
        stop.set()
        thread.join(10)
        peer.close()
    assert not thread.is_alive()


@pytest.mark.slow
def test_every_thumbnail_arrives_intact_through_a_lossy_link_from_the_real_surface_link(tmp_path):
    """The companion's own Downlink (at 4,000 B/s to keep the test short), one datagram in 8 lost each way."""
    from companion.config import MavlinkConfig, SurfaceConfig
    from companion.vision.events import SummaryEvent
    from tests.companion.surface_peer import LossyRelay
    from vehicle.camera.downlink import Downlink
    from vehicle.link.connection import MavLink

    port = free_udp_port()
    stop = threading.Event()
    options = SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", push_timeout_s=4.0, index_refresh_s=2.0)
    thread = threading.Thread(target=serve, args=(options, str(tmp_path)), kwargs={"stop": stop}, daemon=True)
    thread.start()
    rng = random.Random(8)
    relay = LossyRelay(port, drop=lambda n: rng.random() < 1 / 8)
    link = MavLink(f"udpout:127.0.0.1:{relay.port}", MavlinkConfig(system_id=1, component_id=100), name="companion")
    link.start()
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=4000))
    surface.start()
    try:
        frames = [summary_frame(i, depth=5.0 + i, yaw_deg=20 * i, score=0.5 + i / 20) for i in range(1, 6)]
        held: list[int] = []
        for f in frames:
            held.append(f.image_index)
            surface.publish(SummaryEvent("added", f, summary=list(held)))
        held.remove(2)
        surface.publish(SummaryEvent("removed", frames[1], summary=list(held)))

        def settled() -> bool:  # every thumbnail right (a push paired by order is checked against the index)
            g = Gallery(tmp_path)
            caps = {c.image_index: c for c in g.summary()}
            return set(caps) == set(held) and all(
                c.thumbnail and c.score is not None
                and (tmp_path / c.thumbnail).read_bytes() == surface.tree.read(f"/summary/{i}.jpg")
                for i, c in caps.items())

        assert wait_until(settled, 60), Gallery(tmp_path).captures()
        gallery = Gallery(tmp_path)
        for cap in gallery.summary():
            assert (tmp_path / cap.thumbnail).read_bytes() == surface.tree.read(f"/summary/{cap.image_index}.jpg")
            assert abs(cap.depth_m - (5.0 + cap.image_index)) < 1e-6
        assert relay.dropped > 10
    finally:
        stop.set()
        thread.join(10)
        surface.stop()
        link.stop()
        relay.close()


def test_a_tool_started_mid_dive_learns_the_summary_from_the_index(tmp_path):
    port = free_udp_port()
    peer = CompanionPeer(port)  # the companion has been diving: three frames held, one trimmed, nobody listening
    sent = {i: peer.add(summary_frame(i, depth=30.0 + i, yaw_deg=45, score=0.9)) for i in (1, 2, 3)}
    peer.trim(2)
    stop = threading.Event()
    options = SurfaceOptions(connect=f"udpin:127.0.0.1:{port}")
    thread = threading.Thread(target=serve, args=(options, str(tmp_path)), kwargs={"stop": stop}, daemon=True)
    thread.start()
    try:
        def learnt() -> bool:
            peer.heartbeat()
            peer.values(MRL_SUMN=2)  # what a running companion sends every second
            held = {c.image_index: c for c in Gallery(tmp_path).summary()}
            return set(held) == {1, 3} and all(c.thumbnail for c in held.values())

        assert wait_until(learnt, 20), Gallery(tmp_path).captures()
        held = {c.image_index: c for c in Gallery(tmp_path).summary()}
        for i in (1, 3):
            assert (tmp_path / held[i].thumbnail).read_bytes() == sent[i] and held[i].thumbnail_via == "ftp"
            assert (held[i].depth_m, held[i].heading_deg, held[i].score) == (30.0 + i, 45.0, 0.9)
    finally:
        stop.set()
        thread.join(10)
        peer.close()


def test_pushes_pair_by_their_mrl_push_marker_and_are_checked_against_index_crcs(tmp_path):
    """Our companion names each push (MRL_PUSH) and lists each thumbnail's CRC32 in index.json: pushes arriving
    out of order still land on their frames, a corrupt one is caught without a CalcFileCRC32 request, and a push
    for a frame already trimmed goes to removed/, never back into the summary."""
    port = free_udp_port()
    stop = threading.Event()
    options = SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", index_refresh_s=0.5)
    thread = threading.Thread(target=serve, args=(options, str(tmp_path)), kwargs={"stop": stop}, daemon=True)
    thread.start()
    peer = CompanionPeer(port, markers=True, index_crc=True)
    try:
        assert wait_until(lambda: peer.heartbeat() or any(m.get_type() == "HEARTBEAT" for m in peer.received), 10)
        frames = {i: summary_frame(i, depth=20.0 + i, score=0.5 + i / 10) for i in (1, 2, 3, 4, 5)}
        sent = {i: peer.add(frames[i], push=False, announce=i != 4) for i in (1, 2, 3, 4, 5)}  # 4's capture lost
        thumbs = {i: make_thumbnail(frames[i].image) for i in sent}
        peer.trim(5)
        # pushes in another order than the captures: arrival order would give frame 1 the thumbnail of frame 2
        for i in (2, 1, 5, 4):
            peer.push(sent[i], thumbs[i].width, thumbs[i].height, index=i)
        bad = bytearray(sent[3])
        bad[len(bad) // 2] ^= 0xFF  # same size, other bytes: only the CRC tells
        peer.push(bytes(bad), thumbs[3].width, thumbs[3].height, index=3)

        def settled() -> bool:
            held = {c.image_index: c for c in Gallery(tmp_path).summary()}
            return set(held) == {1, 2, 3, 4} and held[3].thumbnail_via == "ftp" and held[4].depth_m and all(
                c.thumbnail for c in held.values())

        assert wait_until(settled, 30), Gallery(tmp_path).captures()
        gallery = Gallery(tmp_path)
        for i in (1, 2, 3, 4):
            cap = gallery.get(i)
            assert (tmp_path / cap.thumbnail).read_bytes() == sent[i], cap
        assert [gallery.get(i).thumbnail_via for i in (1, 2, 4)] == ["push"] * 3
        assert gallery.get(4).depth_m == 24.0  # its marker named it: the capture was asked for again
        five = gallery.get(5)
        assert not five.in_summary and (tmp_path / "removed" / "5.jpg").read_bytes() == sent[5]
        assert not (tmp_path / "summary" / "5.jpg").exists()
        crc_requests = [m for m in peer.received if m.get_type() == "FILE_TRANSFER_PROTOCOL" and m.payload[3] == 14]
        assert crc_requests == []
    finally:
        stop.set()
        thread.join(10)
        peer.close()
    assert not thread.is_alive()
