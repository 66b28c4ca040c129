"""The frame gate on synthetic frames: identical frames skipped, a cut always encoded, the max gap honoured; and
the pipeline's handling of what it skips."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.config import Config, EncoderConfig
from companion.sources.frame import Frame
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.gate import FrameGate
from companion.vision.pipeline import Pipeline


def scene(seed: int, shape=(270, 480)) -> np.ndarray:
    """A textured BGR frame; a different seed is a different scene (a cut)."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (9, 16, 3), dtype=np.uint8)  # blobs that survive the gate's 32x18 view
    return cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def drifted(image: np.ndarray, pixels: int) -> np.ndarray:
    """The same scene panned sideways by ``pixels``, as a slowly moving camera sees it."""
    return np.roll(image, pixels, axis=1)


def test_identical_frames_are_skipped_after_the_first():
    gate = FrameGate("difference", threshold=4.0, max_gap_s=10.0, max_gap_share=0)
    img = scene(1)
    admitted = [gate.admit(img.copy(), t * 0.1) for t in range(20)]
    assert admitted == [True] + [False] * 19
    assert gate.last_difference == 0.0 and (gate.seen, gate.encoded, gate.skipped) == (20, 1, 19)


def test_a_cut_is_always_encoded_and_becomes_the_reference():
    gate = FrameGate("difference", threshold=4.0, max_gap_s=10.0, max_gap_share=0)
    a, b = scene(1), scene(2)
    assert gate.admit(a, 0.0)
    assert not gate.admit(a, 0.1)
    assert gate.admit(b, 0.2), "a different scene must be encoded"
    assert gate.last_difference > 4.0
    assert not gate.admit(b, 0.3), "the cut is now the reference"
    assert gate.admit(a, 0.4), "going back is a cut too"


def test_the_max_gap_encodes_a_static_scene_again():
    gate = FrameGate("difference", threshold=4.0, max_gap_s=1.0, max_gap_share=0)
    img = scene(3)
    times = [i * 0.25 for i in range(13)]  # 3 s at 4 frames/s
    admitted = [t for t in times if gate.admit(img, t)]
    assert admitted == [0.0, 1.0, 2.0, 3.0]


def test_a_slow_drift_is_measured_against_the_last_encoded_frame_not_the_previous_one():
    """Each step is small, but they add up: the gate must fire once the drift from the reference is large."""
    base = scene(4)
    gate = FrameGate("difference", threshold=20.0, max_gap_s=100.0, max_gap_share=0)
    steps = [gate.admit(drifted(base, 2 * i), i * 0.1) for i in range(40)]
    per_step = FrameGate("difference", threshold=20.0, max_gap_s=100.0, max_gap_share=0)
    per_step.admit(base, 0.0)
    per_step.admit(drifted(base, 2), 0.1)
    assert per_step.last_difference < 20.0, "one step alone is below the threshold"
    assert steps[0] and sum(steps) > 1 and not all(steps)


def test_the_share_rule_encodes_a_short_static_run_densely_then_ever_more_sparsely():
    """Online and scale-free: the first 1/share frames are all encoded, then a frame whenever the stretch since the
    last encoded one reaches ``max_gap_share`` of the frames seen so far, so every tenth of any footage's length
    (so far) holds an encoded frame, while the time rule takes over on long footage."""
    gate = FrameGate("difference", threshold=4.0, max_gap_s=1000.0, max_gap_share=0.1)
    img = scene(3)
    encoded = [n for n in range(1, 201) if gate.admit(img, n * 0.1)]  # n: 1-based count of frames seen
    assert encoded[:10] == list(range(1, 11))
    gaps = [b - a for a, b in zip(encoded, encoded[1:], strict=False)]
    assert all(g == math.ceil(0.1 * b) for g, b in zip(gaps, encoded[1:], strict=True)), encoded
    assert gaps == sorted(gaps) and len(encoded) < 40
    for length in (16, 50, 200):  # every tenth of the footage so far holds an encoded frame
        assert all(any(lo < n <= lo + length // 10 + 1 for n in encoded) for lo in range(0, length - length // 10))
    timed = FrameGate("difference", threshold=4.0, max_gap_s=0.5, max_gap_share=0.1)
    late = [n for n in range(1, 601) if timed.admit(img, n * 0.1)][-10:]
    assert [b - a for a, b in zip(late, late[1:], strict=False)] == [5] * 9, "the time rule fires first later on"
    off = FrameGate("difference", threshold=4.0, max_gap_s=1000.0, max_gap_share=0)
    assert sum(off.admit(img, n * 0.1) for n in range(1, 201)) == 1


def test_time_going_backwards_encodes():
    gate = FrameGate("difference", threshold=4.0, max_gap_s=10.0, max_gap_share=0)
    img = scene(5)
    assert gate.admit(img, 5.0)
    assert not gate.admit(img, 5.1)
    assert gate.admit(img, 0.0), "a looped file or a restarted camera starts over"


def test_mode_none_admits_everything_and_changes_apply_at_once():
    gate = FrameGate("none", max_gap_share=0)
    img = scene(6)
    assert all(gate.admit(img, i * 0.1) for i in range(5))
    gate.mode = "difference"
    assert gate.admit(img, 1.0)  # no reference yet
    assert not gate.admit(img, 1.1)
    gate.threshold = 0.0
    assert not gate.admit(img, 1.2), "identical frames stay skipped even at threshold 0"
    assert gate.admit(drifted(img, 1), 1.3)


@pytest.mark.parametrize("kwargs, key", [({"mode": "fast"}, "gate.mode"), ({"threshold": -1}, "gate.threshold"),
                                         ({"max_gap_s": 0}, "gate.max_gap_s"), ({"max_gap_share": 1}, "gate.max_gap_share"),
                                         ({"max_gap_share": -0.1}, "gate.max_gap_share")])
def test_bad_settings_name_the_key(kwargs, key):
    with pytest.raises(ValueError, match=key):
        FrameGate(**{"mode": "difference", **kwargs})


def frames_of(images: list[np.ndarray], fps: float = 10.0, first: int = 0) -> list[Frame]:
    return [Frame(img, i, i / fps, 1000.0 + i / fps) for i, img in enumerate(images, start=first)]


def test_the_pipeline_encodes_only_what_the_gate_admits():
    """Skipped frames count as seen, are not scored and never reach the sampler; the admitted ones go on."""
    cfg = Config.model_validate({"sampler": {"k": 3}, "queries": {"tau_ss": 0.01},
                                 "gate": {"mode": "difference", "threshold": 4.0, "max_gap_s": 100.0,
                                          "max_gap_share": 0}})
    encoder = VisualEncoder(EncoderConfig(name="visual"))
    calls: list[int] = []
    encode = encoder.encode_images
    encoder.encode_images = lambda images: (calls.append(len(images)), encode(images))[1]
    pipe = Pipeline.from_config(cfg, encoder)
    a, b, c = scene(1), scene(2), scene(3)
    frames = frames_of([a, a, a, b, b, c, c, c])
    out = pipe.process(frames)
    encoded = [r.encoded for r in out.results]
    assert encoded == [True, False, False, True, False, True, False, False]
    assert calls == [3], "one encoder call for the three admitted frames"
    assert [r.frame_index for r in out.results] == list(range(8))
    for r in out.results:
        if not r.encoded:
            assert math.isnan(r.score) and not r.passed and not r.offered and not r.added
    assert {e.frame.frame_index for e in out.events if e.kind == "added"} <= {0, 3, 5}
    assert pipe.counts["frames"] == 8 and pipe.counts["encoded"] == 3 and pipe.counts["skipped"] == 5
    out = pipe.process(frames_of([c, c], first=8))  # a batch with nothing new costs no encoder call
    assert not any(r.encoded for r in out.results) and calls == [3] and out.events == []


def test_gate_none_in_the_config_encodes_every_frame():
    cfg = Config.model_validate({"gate": {"mode": "none"}})
    pipe = Pipeline.from_config(cfg, VisualEncoder(EncoderConfig(name="visual")))
    img = scene(1)
    out = pipe.process(frames_of([img] * 4))
    assert all(r.encoded for r in out.results) and pipe.counts["encoded"] == 4
