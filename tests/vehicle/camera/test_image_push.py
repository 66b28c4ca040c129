"""Pushed thumbnails reassembled by an independent pymavlink receiver over real UDP, as QGroundControl does it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.config import SurfaceConfig
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import added, companion_link, ground_station, removed, wait_for
from vehicle.camera.downlink import Downlink
from vehicle.protocol.image_push import CHUNK, ImageReceiver, push_messages


def _receive_images(gcs, count: int, timeout: float = 10.0) -> list[tuple[int, object, bytes]]:
    """Reassembled by the one shared receiver (QGroundControl's rules); the MRL_PUSH value just before a
    handshake names the frame (image index) the image belongs to."""
    done: list[tuple[int, object, bytes]] = []
    rx = ImageReceiver()
    marker = index = hs = None
    while len(done) < count:
        msg = wait_for(gcs, ["DATA_TRANSMISSION_HANDSHAKE", "ENCAPSULATED_DATA", "NAMED_VALUE_INT"],
                       timeout=timeout)
        assert msg is not None, f"only {len(done)} of {count} images arrived"
        if msg.get_type() == "NAMED_VALUE_INT":
            marker = msg.value
            continue
        if msg.get_type() == "DATA_TRANSMISSION_HANDSHAKE":
            assert marker is not None, "a handshake came with no MRL_PUSH marker before it"
            index, marker, hs = marker, None, msg
        image = rx.feed(msg)
        if image is not None:
            done.append((index, hs, image))
    return done


def test_push_messages_are_what_the_protocol_says():
    data = bytes(range(256)) * 3
    msgs = push_messages(data, 160, 90, 80)
    hs = msgs[0]
    assert (hs.type, hs.size, hs.width, hs.height, hs.packets, hs.payload, hs.jpg_quality) == (0, 768, 160, 90, 4, CHUNK, 80)
    assert [m.seqnr for m in msgs[1:]] == [0, 1, 2, 3]
    rx = ImageReceiver()
    for m in msgs:
        out = rx.feed(m)
    assert out == data
    with pytest.raises(ValueError):
        push_messages(b"", 1, 1, 50)


def test_receiver_reassembles_every_pushed_thumbnail_over_udp():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=30000, thumbnail_bytes=2000))
    surface.start()
    gcs = ground_station(port)
    try:
        wait_for(gcs, "HEARTBEAT")
        for i in (1, 2, 3):
            surface.publish(added(i, [1, 2, 3][:i]))
        images = _receive_images(gcs, 3)
        assert [index for index, _, _ in images] == [1, 2, 3]
        for index, hs, data in images:
            assert data == surface.tree.read(f"/summary/{index}.jpg")
            assert len(data) <= 2000
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            assert img.shape[:2] == (hs.height, hs.width)
    finally:
        gcs.close()
        surface.stop()
        link.stop()


def test_thumbnails_of_trimmed_frames_are_not_pushed():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=300))
    surface.publish(added(1, [1]))
    surface.publish(added(2, [1, 2]))
    queued = surface.budget.pending()
    surface.publish(removed(1, [2]))
    assert surface.budget.pending() < queued  # frame 1's chunks left the queue before a byte was sent
    assert surface.tree.read("/summary/1.jpg") is None and surface.tree.read("/summary/2.jpg") is not None
    link.stop()
