"""CLIP's memory rules (issue 14 item 4): the text tower is freed once queries are encoded and re-loaded from the
weights file only for queries not in the cache. (The ONNX runtime, which holds no torch at all, is tested in
test_onnx_clip.py.)

Real open_clip architectures with random weights saved to a checkpoint, loaded through the vehicle's code.
"""

from __future__ import annotations

import numpy as np
import open_clip
import pytest
import torch

from companion.config import EncoderConfig
from companion.vision.encoders.clip import TEXT_TOWER, ClipEncoder

SMALL = "ViT-S-32-alt"
QUERIES = ["a coral reef", "sand", "open water"]


@pytest.fixture(autouse=True)
def _onnx_cache_in_tmp(tmp_path, monkeypatch):
    """Exported ONNX towers are cached between starts: keep the tests' exports out of the user's cache."""
    monkeypatch.setenv("HOME", str(tmp_path))  # the default encoder.cache_dir is ~/.cache/merlion


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> tuple[str, torch.nn.Module]:
    torch.manual_seed(1)
    net = open_clip.create_model(SMALL, pretrained=None)
    path = tmp_path_factory.mktemp("clip_memory") / "small.pt"
    torch.save(net.state_dict(), path)
    return str(path), net.eval()


def _encoder(path: str, **kw) -> ClipEncoder:
    return ClipEncoder(EncoderConfig(name="clip", model=SMALL, weights=path, precision="fp32", batch=2, **kw))


def _text_params(enc: ClipEncoder) -> list[str]:
    return [name for name, _ in enc._model.named_parameters() if name.split(".")[0] in TEXT_TOWER]


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_no_text_tower_is_held_after_loading_nor_after_encoding_queries(ckpt, precision):
    enc = ClipEncoder(EncoderConfig(name="clip", model=SMALL, weights=ckpt[0], precision=precision))
    assert not enc.holds_text_tower and _text_params(enc) == []
    enc.encode_texts(QUERIES)
    assert not enc.holds_text_tower and _text_params(enc) == []
    assert enc.encode_images([np.zeros((120, 160, 3), np.uint8)]).shape == (1, enc._dim)


def test_query_change_reloads_the_text_tower_and_matches_a_fresh_encoder_and_open_clip(ckpt):
    path, net = ckpt
    enc = _encoder(path)
    loads = []
    real_load = enc._load
    enc._load = lambda tower: loads.append(tower) or real_load(tower)  # counts calls, loads for real
    first = enc.encode_texts(QUERIES)
    changed = enc.encode_texts(["a shipwreck", "sand"])
    assert loads == ["text", "text"]
    again = enc.encode_texts(QUERIES[::-1])  # all cached: no reload
    assert loads == ["text", "text"]
    np.testing.assert_array_equal(again, first[::-1])
    np.testing.assert_array_equal(changed[1], first[1])  # "sand" came from the cache

    fresh = _encoder(path).encode_texts(["a shipwreck", "sand"])
    np.testing.assert_allclose(changed, fresh, atol=1e-6)  # batch composition moves the last bits only
    with torch.inference_mode():
        tokens = open_clip.get_tokenizer(SMALL)(["a shipwreck", "sand"])
        ref = torch.nn.functional.normalize(net.encode_text(tokens), dim=-1).numpy()
    np.testing.assert_allclose(changed, ref, atol=1e-5)
    assert not enc.holds_text_tower
