"""Image indices (``companion.vision.image_indices``): int32 is all MAVLink carries, and the end is said once."""

from __future__ import annotations

import logging

from companion.vision.image_indices import ImageIndices
from vehicle.camera.capture_frame import MAX_IMAGE_INDEX


def test_indices_run_up_to_the_last_int32_then_every_frame_is_refused_and_said_once(caplog):
    indices = ImageIndices(MAX_IMAGE_INDEX - 1)
    assert indices.left() and indices.take() == MAX_IMAGE_INDEX - 1
    assert indices.left() and indices.take() == MAX_IMAGE_INDEX
    assert indices.used_up
    with caplog.at_level(logging.ERROR, logger="companion.vision.image_indices"):
        assert [indices.left() for _ in range(3)] == [False, False, False]
    assert indices.refused == 3 and len(caplog.records) == 1 and str(MAX_IMAGE_INDEX) in caplog.records[0].message


def test_a_resumed_store_continues_above_its_frames_and_never_goes_back():
    indices = ImageIndices(5)
    indices.above(41)
    assert indices.next == 42
    indices.above(7)
    assert indices.next == 42 and not indices.used_up and indices.refused == 0
