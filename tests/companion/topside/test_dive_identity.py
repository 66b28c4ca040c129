"""A capture is known by its dive plus its image index: a reset store (new dive, indices from 0 again) never shows
its frames under the last dive's thumbnails, at the surface or on the page."""

from __future__ import annotations

import dataclasses
import shutil
import threading
import time

from companion.commands.surface import serve
from companion.config import MavlinkConfig, StoreConfig, SurfaceConfig
from companion.storage.store import Store
from companion.topside.gallery import Capture, Gallery
from companion.topside.tool import SurfaceOptions
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import summary_frame
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.camera.downlink import Downlink
from vehicle.link.connection import MavLink


def test_the_store_keeps_its_dive_id_until_it_is_reset(tmp_path):
    store = Store(StoreConfig(dir=str(tmp_path / "store")))
    dive = store.dive
    assert len(dive) == 8 and store.index_document()["dive"] == dive
    assert Store(StoreConfig(dir=str(tmp_path / "store"))).dive == dive  # a restart continues the dive
    shutil.rmtree(tmp_path / "store")  # a reset: new dive, new queries
    assert Store(StoreConfig(dir=str(tmp_path / "store"))).dive not in ("", dive)


def _dive(port: int, store_dir, depths: list[float], *, invert: bool = False):
    """One companion run on a store: publish frames 0.. through the real Downlink, return (dive, thumbnails)."""
    store = Store(StoreConfig(dir=str(store_dir)))
    link = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100), name="companion")
    link.start()
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000), dive=store.dive)
    surface.start()
    held: list[int] = []
    for i, depth in enumerate(depths):
        frame = summary_frame(i, depth=depth, score=0.5 + depth / 100)
        if invert:  # another dive's image 0 looks different
            frame = dataclasses.replace(frame, image=255 - frame.image)
        held.append(i)
        event = SummaryEvent("added", frame, summary=list(held))
        store.apply(event)
        surface.publish(event)
    thumbs = {i: surface.tree.read(f"/summary/{store.dive}/{i}.jpg") for i in held}
    return store.dive, thumbs, (surface, link)


def test_gallery_identity_across_a_store_reset(tmp_path):
    port = free_udp_port()
    out = tmp_path / "topside"
    stop = threading.Event()
    options = SurfaceOptions(connect=f"udpin:127.0.0.1:{port}", push_timeout_s=3.0, index_refresh_s=0.5)
    thread = threading.Thread(target=serve, args=(options, str(out)), kwargs={"stop": stop}, daemon=True)
    thread.start()
    time.sleep(0.3)  # the tool binds its port; the companion's udpout would otherwise send into nothing
    running = []
    try:
        first, first_thumbs, parts = _dive(port, tmp_path / "store", [10.0, 11.0, 12.0])
        running.append(parts)

        def shows(dive: str, thumbs: dict[int, bytes]) -> bool:
            g = Gallery(out)
            caps = {c.image_index: c for c in g.summary()}
            return g.dive == dive and set(caps) == set(thumbs) and all(
                c.thumbnail and c.dive == dive and (out / c.thumbnail).read_bytes() == thumbs[i]
                for i, c in caps.items())

        assert wait_until(lambda: shows(first, first_thumbs), 30), Gallery(out).captures()
        surface, link = running.pop()
        surface.stop()
        link.stop()
        shutil.rmtree(tmp_path / "store")  # the vehicle's store is reset: the next run starts at image 0 again
        second, second_thumbs, parts = _dive(port, tmp_path / "store", [40.0, 41.0], invert=True)
        running.append(parts)
        assert second != first and second_thumbs[0] != first_thumbs[0]
        assert wait_until(lambda: shows(second, second_thumbs), 30), Gallery(out).captures()
        gallery = Gallery(out)
        assert {c.depth_m for c in gallery.summary()} == {40.0, 41.0}  # no tag of the first dive leaks in
        old = {c.image_index: c for c in gallery.archived()}
        assert set(old) == {0, 1, 2} and {c.dive for c in old.values()} == {first}
        for i, cap in old.items():  # the first dive's thumbnails are kept, filed under its dive
            assert cap.thumbnail == f"dives/{first}/summary/{i}.jpg"
            assert (out / cap.thumbnail).read_bytes() == first_thumbs[i]
        assert gallery.dives() == [first, second]
    finally:
        stop.set()
        thread.join(10)
        for surface, link in running:
            surface.stop()
            link.stop()


def test_a_late_message_of_an_earlier_dive_is_ignored(tmp_path):
    gallery = Gallery(tmp_path)
    assert gallery.use_dive("aaaa") == "new"
    gallery.announce(Capture(image_index=0, dive="aaaa", depth_m=5.0))
    gallery.add_thumbnail(0, b"old", via="push")
    assert gallery.use_dive("bbbb") == "new"
    assert gallery.use_dive("aaaa") == "old"  # e.g. an index.json asked for before the reset
    assert gallery.use_dive(None) == "current"  # a companion that names no dive
    assert gallery.summary() == [] and (tmp_path / "dives/aaaa/summary/0.jpg").read_bytes() == b"old"
    again = Gallery(tmp_path)  # reopened: the dive history survives
    assert again.dive == "bbbb" and again.use_dive("aaaa") == "old"
