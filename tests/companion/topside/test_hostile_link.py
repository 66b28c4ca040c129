"""The surface tool against a hostile device on the tether: real UDP sockets on 127.0.0.1, real pymavlink messages,
the real FTP server answering. Each test is an attack an earlier helper found, and what the tool must do instead."""

from __future__ import annotations

import json
import threading

import pytest

from companion.topside.gallery import Gallery
from companion.topside.tool import SurfaceOptions, SurfaceTool
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.camera.captures import captured_message


@pytest.fixture
def surface(tmp_path):
    """A surface tool listening on a free UDP port, its receive loop on a thread; yields (tool, port)."""
    port = free_udp_port()
    tool = SurfaceTool(SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", index_refresh_s=0.5),
                       Gallery(tmp_path / "gallery"))
    tool.open()
    stop = threading.Event()
    thread = threading.Thread(target=tool.run, args=(stop,), daemon=True)
    thread.start()
    yield tool, port
    stop.set()
    thread.join(10)
    assert not thread.is_alive()


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
