"""The live companion's counting wrapper hides nothing of the encoder it wraps."""

from __future__ import annotations

import inspect

import numpy as np

from companion.config import EncoderConfig
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.counted import CountedEncoder
from companion.vision.encoders.imagenet import FEATURES, ImageNetEncoder
from companion.vision.presampler import PreSampler


def test_every_method_of_the_interface_is_delegated():
    interface = {name for name, value in inspect.getmembers(Encoder)
                 if not name.startswith("_") and (callable(value) or isinstance(value, property))}
    assert {"scene_input", "with_scene", "encode_images", "input_size"} <= interface
    written = {name for name in vars(CountedEncoder) if not name.startswith("_")}
    assert interface <= written, f"not delegated (the base class's default would answer): {interface - written}"


def test_a_counted_encoder_scores_a_dive_with_the_scene_head_as_the_bare_one_does():
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"))
    counted = CountedEncoder(encoder)
    rng = np.random.default_rng(5)
    scene = rng.integers(40, 120, size=(256, 448, 3), dtype=np.uint8)
    frames = []
    for t in range(6):
        f = np.clip(scene.astype(int) + rng.integers(-6, 7, size=scene.shape), 0, 255).astype(np.uint8)
        if t % 2:
            f[100:130, 200:240] = (200, 190, 120)  # something small comes and goes
        frames.append(f)
    emb = counted.encode_images(frames)
    assert counted.images == 6 and counted.calls == 1
    assert counted.scene_input(emb) is not None
    bare = PreSampler(encoder, "fish").scores(emb)
    wrapped = PreSampler(counted, "fish").scores(emb)
    np.testing.assert_allclose(wrapped, bare, atol=1e-7)
    # after the dive's first frame the scene head answers, not the pooled head
    pooled = next(h for h in encoder.heads if h.input == "pooled").probabilities(emb[:, :FEATURES])
    assert wrapped[0] == np.float32(pooled[0]) or abs(wrapped[0] - pooled[0]) < 1e-6
    assert np.abs(wrapped[1:] - pooled[1:]).max() > 1e-3
