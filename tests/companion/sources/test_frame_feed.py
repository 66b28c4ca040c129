"""The decode-ahead feed: bounded in pixels as well as in frames, in order, and skipped frames without pixels."""

from __future__ import annotations

import time

import numpy as np

from companion.sources.frame_feed import FrameFeed
from companion.sources.synthetic import SyntheticSource
from companion.vision.gate import FrameGate
from tests.waiting import wait_until

HD = "synthetic://dive?width=1920&height=1080&seconds=2"
HD_BYTES = 1920 * 1080 * 3


def test_read_ahead_stops_at_max_bytes_of_pixels_and_delivers_every_frame_in_order():
    """A slow consumer: the decode thread fills the read-ahead up to four 1080p frames, never five, although
    its item bound (depth 32) would let it hold 32."""
    frames = 16
    with FrameFeed(SyntheticSource(HD, fps=5, realtime=False), limit=frames, max_bytes=4 * HD_BYTES) as feed:
        got = []
        for batch in feed.batches(2):
            if not got:  # the decoder runs into the bound, then has time to decode a fifth if it were let
                assert wait_until(lambda: feed.most_bytes_ahead >= 4 * HD_BYTES, 30)
                time.sleep(0.5)
            got += [frame.index for frame, _ in batch]
            assert all(frame.image.shape == (1080, 1920, 3) for frame, _ in batch)
    assert got == list(range(frames))
    assert feed.most_bytes_ahead == 4 * HD_BYTES


def test_a_frame_larger_than_max_bytes_still_passes_one_at_a_time():
    with FrameFeed(SyntheticSource(HD, fps=5, realtime=False), limit=3, max_bytes=1) as feed:
        got = [frame.index for batch in feed.batches(4) for frame, _ in batch]
    assert got == [0, 1, 2] and feed.most_bytes_ahead == HD_BYTES


def test_frames_the_gate_skips_travel_without_pixels_and_do_not_count_against_max_bytes():
    """A still camera: after the first frame the gate skips all but its max-gap frames. Skipped frames carry an
    empty image (nothing downstream reads it), so the read-ahead holds their place, not their 6 MB."""
    class Still(SyntheticSource):
        def render(self, index: int) -> np.ndarray:
            return super().render(0)

    gate = FrameGate(mode="difference", threshold=8.0, max_gap_s=2.0, max_gap_share=0)
    with FrameFeed(Still(HD, fps=5, realtime=False), lambda img: img[::8, ::8], limit=20, gate=gate,
                   max_bytes=2 * HD_BYTES) as feed:
        items = [item for batch in feed.batches(4) for item in batch]
    assert [frame.index for frame, _ in items] == list(range(20))
    encoded = [frame for frame, small in items if small is not None]
    skipped = [frame for frame, small in items if small is None]
    assert [f.index for f in encoded] == [0, 10]  # the first, then the max gap (2 s at 5 frames/s)
    assert all(f.image.shape == (1080, 1920, 3) for f in encoded)
    assert len(skipped) == 18 and all(f.image.size == 0 for f in skipped)
    assert feed.most_bytes_ahead <= 2 * HD_BYTES
