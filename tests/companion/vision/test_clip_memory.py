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
from tests.companion.vision.helpers import resident_kb_of

SMALL = "ViT-S-32-alt"
QUERIES = ["a coral reef", "sand", "open water"]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> tuple[str, torch.nn.Module]:
    torch.manual_seed(1)
    net = open_clip.create_model(SMALL, pretrained=None)
    path = tmp_path_factory.mktemp("clip_memory") / "small.pt"
    torch.save(net.state_dict(), path)
    return str(path), net.eval()


def _encoder(path: str, **kw) -> ClipEncoder:
    return ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=path, precision="fp32", batch=2, **kw))


def _text_params(enc: ClipEncoder) -> list[str]:
    return [name for name, _ in enc._model.named_parameters() if name.split(".")[0] in TEXT_TOWER]


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_no_text_tower_is_held_after_loading_nor_after_encoding_queries(ckpt, precision):
    enc = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=ckpt[0], precision=precision))
    assert not enc.holds_text_tower and _text_params(enc) == []
    enc.encode_texts(QUERIES)
    assert not enc.holds_text_tower and _text_params(enc) == []
    assert enc.encode_images([np.zeros((120, 160, 3), np.uint8)]).shape == (1, enc._dim)


@pytest.mark.slow
def test_queries_are_encoded_in_a_child_once_then_come_from_the_disk_cache(ckpt, tmp_path):
    path, net = ckpt
    cfg = EncoderConfig(name="clip", device="cpu", model=SMALL, weights=path, precision="fp32", cache_dir=str(tmp_path))
    enc = ClipEncoder(cfg)
    first = enc.encode_texts(QUERIES)
    assert enc._texts.children == 1 and enc.child_peaks_mb["texts"] > 0
    changed = enc.encode_texts(["a shipwreck", "sand"])  # a query change: only the new text needs the child
    assert enc._texts.children == 2
    again = enc.encode_texts(QUERIES[::-1])  # all known: no child
    assert enc._texts.children == 2
    np.testing.assert_array_equal(again, first[::-1])
    np.testing.assert_array_equal(changed[1], first[1])  # "sand" came from the cache
    assert not enc.holds_text_tower and _text_params(enc) == []

    restarted = ClipEncoder(cfg)  # a later start reads them all from the disk cache
    np.testing.assert_array_equal(restarted.encode_texts(["a shipwreck", *QUERIES]),
                                  np.concatenate([changed[:1], first]))
    assert restarted._texts.children == 0
    with torch.inference_mode():  # and they are open_clip's own text embeddings
        tokens = open_clip.get_tokenizer(SMALL)(["a shipwreck", "sand"])
        ref = torch.nn.functional.normalize(net.encode_text(tokens), dim=-1).numpy()
    np.testing.assert_allclose(changed, ref, atol=1e-5)


def test_a_cast_of_mapped_weights_gives_back_their_file_pages_and_equals_a_plain_cast(ckpt):
    from pathlib import Path

    from companion.vision.encoders.clip import read_state_dict
    from companion.vision.encoders.mapped_cast import cast_dropping_file_pages

    path, net = ckpt
    mapped = open_clip.create_model(SMALL, pretrained=None, device="meta")
    mapped.load_state_dict(read_state_dict(Path(path)), strict=False, assign=True)  # tensors in the mapped file
    mapped.visual = cast_dropping_file_pages(mapped.visual, torch.bfloat16, Path(path))
    plain = {k: v.to(torch.bfloat16) for k, v in net.visual.state_dict().items()}
    got = mapped.visual.state_dict()
    assert got.keys() == plain.keys()
    for key, want in plain.items():
        assert got[key].dtype == torch.bfloat16 and torch.equal(got[key], want), key
    assert resident_kb_of(path) < 0.05 * Path(path).stat().st_size / 1024  # every fp32 page read was given back
    cast = mapped.text_projection  # the text tower was not cast: still fp32, still read from the file
    assert cast.dtype == torch.float32 and torch.equal(cast, net.text_projection)


def test_an_int8_tower_leaves_none_of_the_checkpoint_resident(ckpt, tmp_path):
    """Quantization reads the fp32 pages and something in the quantized tower keeps the mapping alive: the pages
    are given back (and nothing reads them again while frames are encoded)."""
    from pathlib import Path

    own = tmp_path / "own.pt"  # a file no other encoder of this test process maps
    own.write_bytes(Path(ckpt[0]).read_bytes())
    enc = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=str(own), precision="int8"))
    enc.encode_images([np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)] * 2)
    assert resident_kb_of(str(own)) < 0.05 * own.stat().st_size / 1024


def test_queries_are_served_when_the_cache_cannot_be_written(ckpt, tmp_path):
    """The service user has no writable home (ProtectHome, no home at all): the child's answer carries the
    embeddings, so the queries work and only the cache for later starts is missing (warned)."""
    path, net = ckpt
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder would go: nothing can be created below it\n")
    enc = _encoder(path, cache_dir=str(blocker / "merlion"))
    got = enc.encode_texts(["a kelp forest", "sand"])
    assert enc._texts.children == 1
    with torch.inference_mode():
        tokens = open_clip.get_tokenizer(SMALL)(["a kelp forest", "sand"])
        ref = torch.nn.functional.normalize(net.encode_text(tokens), dim=-1).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-5)
    np.testing.assert_array_equal(enc.encode_texts(["sand"]), got[1:])  # from memory: no second child
    assert enc._texts.children == 1


def test_the_cache_goes_where_systemd_or_xdg_says(monkeypatch, tmp_path):
    from companion.vision.encoders.clip_cache import cache_root

    monkeypatch.setenv("CACHE_DIRECTORY", f"{tmp_path}/svc:/other")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root(None) == tmp_path / "svc"  # the unit's CacheDirectory=merlion
    assert cache_root(str(tmp_path / "mine")) == tmp_path / "mine"  # encoder.cache_dir wins
    monkeypatch.delenv("CACHE_DIRECTORY")
    assert cache_root(None) == tmp_path / "xdg" / "merlion"


def test_weights_replaced_at_the_same_path_get_a_fresh_cache(tmp_path):
    """A checkpoint overwritten in place (new weights, same name) must never be served the old tower or the old
    query embeddings: the key follows the file's size and modification time."""
    import os

    from companion.vision.encoders.clip_cache import ClipCache

    weights = tmp_path / "clip.pt"
    weights.write_bytes(b"old weights")
    old = ClipCache(tmp_path / "cache", weights, SMALL)
    old.put_text("sand", np.ones(4, np.float32))
    stat = weights.stat()
    weights.write_bytes(b"new weights")  # same size: only the time tells them apart
    os.utime(weights, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    new = ClipCache(tmp_path / "cache", weights, SMALL)
    assert new.onnx_path != old.onnx_path and new.text_dir != old.text_dir
    assert new.texts(["sand"]) == {} and "sand" in old.texts(["sand"])


def test_a_tag_declaring_other_preprocessing_gets_its_own_cache_for_the_same_file(tmp_path):
    from companion.vision.encoders.clip_cache import ClipCache

    weights = tmp_path / "clip.pt"
    weights.write_bytes(b"weights")
    plain = ClipCache(tmp_path / "cache", weights, SMALL)
    tagged = ClipCache(tmp_path / "cache", weights, SMALL, {"mean": [0.5, 0.5, 0.5], "std": [0.5, 0.5, 0.5]})
    again = ClipCache(tmp_path / "cache", weights, SMALL, {"std": (0.5, 0.5, 0.5), "mean": (0.5, 0.5, 0.5)})
    assert tagged.manifest_path != plain.manifest_path and tagged.text_dir != plain.text_dir
    assert again.manifest_path == tagged.manifest_path  # the same overrides, whatever their order or JSON form
    assert ClipCache(tmp_path / "cache", weights, SMALL, {}).manifest_path == plain.manifest_path
