"""The frame gate on the capture thread (issue 46, 1080p60): a frame the gate skips is queued without pixels and
bounded apart from the frames to encode, so a burst of skipped frames while the encoder runs a batch loses none;
the inference step counts them, scores the admitted ones, and the surface's gate settings still apply."""

from __future__ import annotations

import threading

import cv2
import numpy as np

from companion.config import Config, EncoderConfig, StoreConfig
from companion.live.health import Health
from companion.live.loops import (
    Admitted,
    CaptureLoop,
    FrameAdmission,
    InferenceLoop,
    LiveCounters,
    halved,
    is_skipped,
)
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.sources.retrying import RetryingSource
from companion.sources.synthetic import SyntheticSource
from companion.storage.store import Store
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.pipeline import Pipeline


def test_skipped_frames_are_light_and_only_frames_to_encode_are_dropped() -> None:
    q: DropOldestQueue[str] = DropOldestQueue(2, light=lambda s: s.startswith("skip"), light_max=5)
    assert q.put("enc0") and q.put("skip0") and q.put("enc1")
    assert all(q.put(f"skip{i}") for i in range(1, 5))
    assert q.dropped == 0 and len(q) == 7
    assert q.put("enc2") is False  # a third frame to encode: the oldest one to encode goes, no skipped one
    assert q.dropped == 1 and "enc0" not in list(q._items)
    assert q.put("skip5") is False  # the sixth skipped one: the oldest skipped one goes
    assert q.dropped == 2
    assert q.get_batch(1, timeout=0) == ["enc1"]  # one frame to encode asked for: the batch ends with it
    assert q.get_batch(1, timeout=0) == ["skip1", "skip2", "skip3", "skip4", "enc2"]  # the skipped ride along
    assert q.get_batch(8, timeout=0) == ["skip5"]


def _pipeline(tmp_path, gate: dict) -> tuple[Pipeline, SummaryKeeper]:
    cfg = Config.model_validate({"queries": {"tau_ss": 0.01}, "gate": gate})
    pipeline = Pipeline.from_config(cfg, VisualEncoder(EncoderConfig(name="visual")))
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {})
    return pipeline, keeper


def test_a_burst_of_near_identical_frames_is_admitted_without_a_drop_and_counted(tmp_path) -> None:
    pipeline, keeper = _pipeline(tmp_path, {"mode": "difference", "threshold": 4.0, "max_gap_s": 100.0,
                                            "max_gap_share": 0})
    admit = FrameAdmission(pipeline.prepare, lambda: pipeline.gate, pipeline.encode_size)
    queue = DropOldestQueue(4, light=is_skipped, light_max=512)
    still = cv2.resize(np.random.default_rng(1).integers(0, 256, (9, 16, 3), dtype=np.uint8), (1920, 1080))
    other = cv2.resize(np.random.default_rng(2).integers(0, 256, (9, 16, 3), dtype=np.uint8), (1920, 1080))
    # one second at 60 fps while the encoder is busy (nobody takes from the queue): two scenes, a cut at 0.5 s
    for i in range(60):
        queue.put(admit(Frame(still if i < 30 else other, i, i / 60, 1000.0 + i / 60)))
    assert queue.dropped == 0 and len(queue) == 60  # four places held every frame to encode with room to spare
    assert admit.frames == 60 and pipeline.gate.encoded == 2
    items = queue.get_batch(8, timeout=0)
    assert [a.frame.index for a in items if a.prepared is not None] == [0, 30]
    assert all(a.frame.image.size == 0 for a in items if a.prepared is None)  # skipped: no 6-MB image kept
    assert all(a.prepared.shape[0] < 1080 for a in items if a.prepared is not None)  # the encoder's copy
    counters = LiveCounters()
    loop = InferenceLoop(pipeline, queue, Health(10.0), counters, threading.Event(), batch=8, pose_at=None,
                         keeper=keeper)
    loop.step([a.frame for a in items], [a.prepared for a in items])
    assert (counters.frames_scored, counters.frames_skipped) == (2, 58)
    assert pipeline.counts["skipped"] == 58 and pipeline.counts["frames"] == 60
    pipeline.gate.mode = "none"  # MERL_GATE 0 from the surface: the next frame is admitted at once
    assert admit(Frame(still, 60, 1.0, 1001.0)).prepared is not None


def test_the_capture_thread_admits_a_real_source_and_the_inference_thread_scores_it(tmp_path) -> None:
    pipeline, keeper = _pipeline(tmp_path, {"mode": "difference", "threshold": 8.0, "max_gap_s": 0.5})
    source = RetryingSource(lambda: SyntheticSource("synthetic://dive?seconds=1&segments=2", fps=30.0,
                                                    realtime=False), name="synthetic", live=False, loop=False)
    queue = DropOldestQueue(10_000, light=is_skipped, light_max=10_000)  # a consumer that never falls behind
    counters = LiveCounters()
    capture = CaptureLoop(source, queue, Health(10.0), counters, threading.Event(),
                          FrameAdmission(pipeline.prepare, lambda: pipeline.gate))
    capture.start()
    assert capture.ended.wait(120)
    items: list[Admitted] = queue.get_batch(10_000, timeout=0)
    assert len(items) == counters.frames_seen == 60 and capture.admit_clock[1] == 60
    loop = InferenceLoop(pipeline, queue, Health(10.0), counters, threading.Event(), batch=8, pose_at=None,
                         keeper=keeper)
    for start in range(0, len(items), 20):
        chunk = items[start:start + 20]
        loop.step([a.frame for a in chunk], [a.prepared for a in chunk])
    encoded = sum(a.prepared is not None for a in items)
    assert 4 <= encoded < 60 and counters.frames_scored == encoded
    assert counters.frames_scored + counters.frames_skipped == 60 and queue.dropped == 0


def test_halving_keeps_the_encoders_input_covered_and_its_copy_the_same_size() -> None:
    frame = cv2.resize(np.random.default_rng(3).integers(0, 256, (9, 16, 3), dtype=np.uint8), (1920, 1080))
    assert halved(frame, (224, 224)).shape == (270, 480, 3)  # a third halving would leave 135 rows < 224
    assert halved(frame, (960, 540)).shape == (540, 960, 3) and halved(frame, (961, 540)).shape == frame.shape
    odd = frame[:1079]
    assert halved(odd, (224, 224)) is odd  # no exact half: left to the one resize
    pipeline, _ = _pipeline_only()
    direct, quick = pipeline.prepare(frame), pipeline.prepare(halved(frame, pipeline.encode_size))
    assert quick.shape == direct.shape
    assert np.abs(quick.astype(float) - direct.astype(float)).mean() < 4.0  # the same picture


def _pipeline_only() -> tuple[Pipeline, None]:
    return Pipeline.from_config(Config(), VisualEncoder(EncoderConfig(name="visual"))), None
