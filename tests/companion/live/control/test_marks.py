"""Marks on a companion that enhances (in-process, no vehicle link): a marked frame teaches as it was captured,
with the score it was kept with.

With selective enhancement the store holds each summary frame enhanced, and the frame as captured beside it
(``store.keep_raw``). The marks are compared with raw frames in the dive of raw frames, and an enhanced copy is
judged by its raw frame's row there, so a mark's features must be its raw frame's, not the enhancer's colours.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from companion.config import build_config
from companion.live.companion import LiveCompanion
from companion.vision.feedback import MarkedPreSampler
from tests.waiting import wait_until


def test_a_mark_on_an_enhanced_frame_teaches_the_frame_as_captured(tmp_path: Path) -> None:
    cfg = build_config({
        "source": {"uri": "synthetic://dive?seconds=4&width=160&height=96", "fps": 10, "realtime": False},
        "encoder": {"name": "visual"}, "queries": {"positive": "underwater image with fish", "tau_ss": 0.5},
        # K above the dive's 40 frames: none leaves the summary, so the test and the marks read the same frames
        # from memory (a trimmed one is read back from its JPEG, whose pixels differ; this once raced under load)
        "enhance": {"mode": "selective", "tau_ses": 0.5}, "sampler": {"k": 50},
        "mavlink": {"connection": None}, "store": {"dir": str(tmp_path / "store")},
    })
    app = LiveCompanion(cfg)
    app.start()
    try:
        assert wait_until(lambda: len(app.store.summary) >= 2, 60), "enhanced frames stored"
        like, unlike = app.store.summary[:2]
        frames = [app.store.frame(i) for i in (like, unlike)]
        assert all(f.enhanced and f.raw_image is not None for f in frames)
        # stand-ins for the scores they were kept with (the held frames are the store's own objects): the marks
        # must read these, not score the images again out of their dive
        frames[0].raw_score, frames[1].raw_score = 0.987, 0.012
        app.on_marks([like], [unlike])
        gate = app.selective.raw.presamplers[cfg.queries.name]
        assert isinstance(gate, MarkedPreSampler) and isinstance(app.pipeline.presampler, MarkedPreSampler)
        marks = gate.examples.marks
    finally:
        app.stop()

    def pooled(image):
        return app.encoder.sampler_features(app.encoder.encode_images([app.pipeline.prepare(image)]))[0]

    # the marks' query scores are the raw frames' own in their dive (what the marks' doubt of the query reads)
    np.testing.assert_allclose([marks.like_query[0], marks.unlike_query[0]], [0.987, 0.012])
    for got, frame in zip((marks.like_pooled[0], marks.unlike_pooled[0]), frames, strict=True):
        np.testing.assert_allclose(got, pooled(frame.raw_image), rtol=1e-5, atol=1e-6)
        assert not np.allclose(got, pooled(frame.image), rtol=1e-3, atol=1e-4)  # the enhanced copy differs
