"""The surface tool against a sender without the key that makes its state grow: new dives without end, captures
no push ever comes for, and made-up sequence numbers under the vehicle's own ids. Real UDP sockets on 127.0.0.1,
real pymavlink messages, the real FTP server answering (helpers from ``test_hostile_link``)."""

from __future__ import annotations

import json

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.topside.gallery import Gallery
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.companion.topside.test_hostile_link import _paced, meet, running_tool
from tests.waiting import wait_until


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

