"""The live inference step with the frame gate: skipped frames are counted apart from scored ones, and MERL_GATE
maps to the gate's settings."""

from __future__ import annotations

import threading

import cv2
import numpy as np

from companion.config import Config, EncoderConfig, StoreConfig
from companion.live.control.params import default_params, gate_param
from companion.live.health import Health
from companion.live.loops import InferenceLoop, LiveCounters
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.storage.store import Store
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.pipeline import Pipeline


def _scene(seed: int) -> np.ndarray:
    coarse = np.random.default_rng(seed).integers(0, 256, (9, 16, 3), dtype=np.uint8)
    return cv2.resize(coarse, (480, 270), interpolation=cv2.INTER_CUBIC)


def test_inference_counts_skipped_frames_apart_from_scored_ones(tmp_path):
    cfg = Config.model_validate({"queries": {"tau_ss": 0.01},
                                 "gate": {"mode": "difference", "threshold": 4.0, "max_gap_s": 100.0,
                                          "max_gap_share": 0}})
    pipeline = Pipeline.from_config(cfg, VisualEncoder(EncoderConfig(name="visual")))
    counters = LiveCounters()
    events: list = []
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {}, publish=events.append)
    loop = InferenceLoop(pipeline, DropOldestQueue(8), Health(10.0), counters, threading.Event(), batch=8,
                         pose_at=None, keeper=keeper)
    a, b = _scene(1), _scene(2)
    frames = [Frame(img, i, i * 0.1, 1000.0 + i * 0.1) for i, img in enumerate([a, a, a, b, b])]
    loop.step(frames)
    assert (counters.frames_scored, counters.frames_skipped) == (2, 3)
    assert len(counters.recent) == 2, "the frames/s figure counts scored frames only"
    assert events and all(e.frame.frame_index in (0, 3) for e in events if e.kind == "added")
    pipeline.gate.mode = "none"  # what MERL_GATE 0 does
    loop.step([Frame(b, 5, 0.5, 1000.5)])
    assert (counters.frames_scored, counters.frames_skipped) == (3, 3)


def test_merl_gate_is_the_threshold_and_zero_means_off():
    params = {p.name: p for p in default_params(Config())}
    assert params["MERL_GATE"].value == Config().gate.threshold and not params["MERL_GATE"].integer
    assert gate_param("none", 8.0) == 0.0 and gate_param("difference", 5.5) == 5.5


def test_selective_enhancement_is_gated_too_enhancer_on_or_off(tmp_path):
    """enhance.mode selective: the gate runs ahead of the raw scoring (only admitted frames are encoded and can
    become candidates) and, with MERL_ENHANCE 0, ahead of the pipeline the frames then go straight to."""
    from companion.live.enhance_worker import SelectiveStage
    from companion.live.raw_gate import RawGate
    from companion.vision.encoders.counted import CountedEncoder
    from companion.vision.gate import FrameGate
    from companion.vision.topics import TopicSpec

    encoder = CountedEncoder(VisualEncoder(EncoderConfig(name="visual")))
    cfg = Config.model_validate({"queries": {"tau_ss": 0.01}, "gate": {"mode": "none"}})
    pipeline = Pipeline.from_config(cfg, encoder)
    keeper = SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {})
    raw = RawGate(encoder, [TopicSpec("main", "anything", ())], tau_ss=0.01)
    stage = SelectiveStage(pipeline, raw, enhancer=None, queue_size=16, lock=keeper.lock,
                           gate=FrameGate("difference", 4.0, 100.0, max_gap_share=0))
    counters = LiveCounters()
    loop = InferenceLoop(pipeline, DropOldestQueue(8), Health(10.0), counters, threading.Event(), batch=8,
                         pose_at=None, keeper=keeper, selective=stage)
    a, b, c = _scene(1), _scene(2), _scene(3)
    frames = [Frame(img, i, i * 0.1, 1000.0 + i * 0.1) for i, img in enumerate([a, a, a, b, b])]
    images = encoder.images
    loop.step(frames)
    assert encoder.images - images == 2 and (counters.frames_scored, counters.frames_skipped) == (2, 3)
    assert [cand.frame.index for cand in stage.queue.get_batch(16, timeout=0.1)] == [0, 3]

    stage.on = False  # MERL_ENHANCE 0: frames go to the pipeline, still behind the stage's gate
    images = encoder.images
    loop.step([Frame(img, 5 + i, 0.5 + i * 0.1, 1000.5 + i * 0.1) for i, img in enumerate([b, c, c])])
    assert encoder.images - images == 1 and (counters.frames_scored, counters.frames_skipped) == (3, 5)
    assert [f.frame_index for f in pipeline.summary] == [6]

    stage.gate.mode = "none"  # what MERL_GATE 0 does in selective mode
    images = encoder.images
    loop.step([Frame(c, 8, 0.8, 1000.8)])
    assert encoder.images - images == 1 and counters.frames_skipped == 5
