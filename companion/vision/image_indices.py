"""The summary frames' image indices: one running number per companion, carried by MAVLink as an int32.

CAMERA_IMAGE_CAPTURED.image_index is an int32, so 2^31 - 1 (``MAX_IMAGE_INDEX``) is the last index a frame can be
announced under. Past it no new frame enters a summary (reusing an index would overwrite a stored frame under the
same dive id); the first refusal is said once, as an error, and every refusal is counted.
"""

from __future__ import annotations

import logging

from vehicle.camera.capture_frame import MAX_IMAGE_INDEX

log = logging.getLogger(__name__)


class ImageIndices:
    """The next index to hand out, and how many frames found none left."""

    def __init__(self, first: int = 0) -> None:
        self.next = int(first)
        self.refused = 0
        """Frames that would have entered a summary but found every image index used."""

    @property
    def used_up(self) -> bool:
        """Every index MAVLink can carry was handed out: no new frame can enter."""
        return self.next > MAX_IMAGE_INDEX

    def left(self) -> bool:
        """True while an index is left; the first frame refused for want of one is said, as an error, once."""
        if not self.used_up:
            return True
        if not self.refused:
            log.error("image index %d was the last MAVLink can carry (CAMERA_IMAGE_CAPTURED.image_index is an "
                      "int32): no new frame enters the summary; move the store aside to start a new one",
                      MAX_IMAGE_INDEX)
        self.refused += 1
        return False

    def take(self) -> int:
        """The next index, now handed out (call ``left()`` first)."""
        key = self.next
        self.next += 1
        return key

    def above(self, index: int) -> None:
        """Continue above an index already in use (a resumed store's frames)."""
        self.next = max(self.next, int(index) + 1)
