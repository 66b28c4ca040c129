"""precision fp16-weights: fp32 arithmetic on weights kept in fp16 (what `auto` runs on CPUs without bf16 units).

Real open_clip architectures with random weights saved to checkpoints, loaded through the vehicle's code; the
memory side (one copy at load, under half the fp32 tower) is in test_encoders_clip.py's load-peak test.
"""

from __future__ import annotations

import numpy as np
import open_clip
import pytest
import torch

from companion.config import EncoderConfig
from companion.errors import UsageError
from companion.vision.encoders import torch_runtime
from companion.vision.encoders.clip import ClipEncoder
from companion.vision.encoders.half_weights import MIN_ELEMENTS, store_weights_in_fp16, stored_in_fp16
from companion.vision.encoders.torch_runtime import pick_precision
from tests.companion.vision.helpers import resident_kb_of

SMALL = "ViT-S-32-alt"


def _checkpoint(tmp_path_factory, dtype: torch.dtype) -> str:
    torch.manual_seed(3)
    net = open_clip.create_model(SMALL, pretrained=None)
    path = tmp_path_factory.mktemp("half") / f"small_{str(dtype).split('.')[-1]}.pt"
    torch.save({k: v.to(dtype) if v.is_floating_point() else v for k, v in net.state_dict().items()}, path)
    return str(path)


@pytest.fixture(scope="module")
def fp32_ckpt(tmp_path_factory) -> str:
    return _checkpoint(tmp_path_factory, torch.float32)


@pytest.fixture(scope="module")
def fp16_ckpt(tmp_path_factory) -> str:
    """Values fp16 holds exactly, as in checkpoints trained in mixed precision (OpenAI's CLIP was released so)."""
    return _checkpoint(tmp_path_factory, torch.float16)


def _pair(path: str) -> tuple[ClipEncoder, ClipEncoder]:
    return tuple(ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=path, precision=p, batch=3))
                 for p in ("fp32", "fp16-weights"))


def test_the_tower_keeps_its_large_weights_in_fp16_and_computes_in_fp32(fp32_ckpt, images):
    full, half = _pair(fp32_ckpt)
    assert half.describe()["precision"] == "fp16-weights"
    stored = set(stored_in_fp16(half._model.visual))
    large = {name for name, p in full._model.visual.named_parameters() if p.numel() >= MIN_ELEMENTS}
    assert large and {n.replace(".parametrizations", "").replace(".original", "") for n in stored} == large
    small = [p for p in half._model.visual.parameters() if p.numel() < MIN_ELEMENTS]
    assert small and all(p.dtype == torch.float32 for p in small)
    held = sum(t.numel() * t.element_size() for t in half._model.visual.state_dict().values())
    whole = sum(t.numel() * t.element_size() for t in full._model.visual.state_dict().values())
    assert held < 0.52 * whole, (held, whole)  # half of the fp32 tower, plus its small fp32 tensors
    got, want = half.encode_images(images), full.encode_images(images)
    assert got.dtype == np.float32
    cos = np.sum(got * want, axis=1)
    assert cos.min() > 0.9999, cos  # fp16 rounding of the weights only (bf16 reaches ~0.999)
    queries = full.encode_images(images[::-1])  # random towers' text embeddings are alike: spread with images
    np.testing.assert_allclose(half.semantic_scores(got, queries), full.semantic_scores(want, queries), atol=2e-3)


def test_a_checkpoint_saved_in_fp16_gives_fp32_s_embeddings_exactly(fp16_ckpt, images):
    """The weights lose nothing when fp16 holds them: what differs from fp32 is then only summation order."""
    full, half = _pair(fp16_ckpt)
    np.testing.assert_allclose(half.encode_images(images), full.encode_images(images), atol=1e-5)
    assert stored_in_fp16(half._model.visual)


def test_a_tensor_fp16_cannot_hold_stays_fp32():
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(512, 256), torch.nn.Linear(256, 512), torch.nn.Linear(512, 256))
    with torch.no_grad():
        net[1].weight[0, 0] = 1e6  # beyond fp16's 65504
        net[2].weight.mul_(1e-6)  # mostly fp16 subnormals: large relative error
    x = torch.randn(4, 512)
    want = net(x)
    saved = store_weights_in_fp16(net)
    assert stored_in_fp16(net) == ["0.weight"]
    assert saved == 512 * 256 * 2
    assert net[1].weight.dtype == net[2].weight.dtype == torch.float32
    assert net[0].weight.dtype == torch.float32  # what the layer sees: upcast from its fp16 storage
    assert net[0].parametrizations.weight.original.dtype == torch.float16
    torch.testing.assert_close(net(x), want, atol=2e-3, rtol=1e-3)


def test_precision_auto_follows_the_cpu(monkeypatch):
    assert pick_precision("auto", torch.device("cuda")) == "fp16"
    monkeypatch.setattr(torch_runtime, "cpu_has_native_bf16", lambda: True)
    assert pick_precision("auto", torch.device("cpu")) == "bf16"
    monkeypatch.setattr(torch_runtime, "cpu_has_native_bf16", lambda: False)  # an AVX2-only CPU
    assert pick_precision("auto", torch.device("cpu")) == "fp16-weights"
    for explicit in ("fp32", "fp16-weights", "bf16", "fp16", "int8"):
        assert pick_precision(explicit, torch.device("cpu")) == explicit
    for cpu_only in ("int8", "fp16-weights"):
        with pytest.raises(UsageError, match=f"encoder.precision: {cpu_only} runs on the CPU only"):
            pick_precision(cpu_only, torch.device("cuda"))


def test_each_stored_weight_is_upcast_about_once_per_forward(fp32_ckpt):
    """nn.MultiheadAttention reads its projection weights several times per call, and each read would upcast them
    again (ViT-B-32: 687 MB of upcasts per forward instead of 352). Only the tower's own final projection, read
    twice by its forward and too small to matter, is not held for the call."""
    from companion.vision.encoders.half_weights import UpcastToFloat32

    half = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=fp32_ckpt, precision="fp16-weights"))
    visual = half._model.visual
    calls: dict[str, int] = {}
    for name, module in visual.named_modules():
        if isinstance(module, UpcastToFloat32):
            module.register_forward_hook(lambda mod, args, out, name=name: calls.update({name: calls.get(name, 0) + 1}))
    half.encode_images([np.zeros((240, 320, 3), np.uint8)] * 2)
    stored = stored_in_fp16(visual)
    assert len(calls) == len(stored) > 0
    attention = [n for n, m in visual.named_modules() if isinstance(m, torch.nn.MultiheadAttention)]
    assert attention and all(calls[f"{n}.parametrizations.in_proj_weight.0"] == 1 for n in attention)
    assert all(count == 1 for name, count in calls.items() if name != "parametrizations.proj.0"), calls


def test_upcasts_are_written_into_one_buffer_that_every_call_reuses(fp32_ckpt):
    """No fresh fp32 tensor per weight and call: every upcast read inside a layer's call is a view of the one
    buffer, at the same place at every forward (the tower's final projection, read outside any layer, is not)."""
    from companion.vision.encoders.half_weights import MAX_CALL_CACHE_BYTES, UpcastToFloat32

    half = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=fp32_ckpt, precision="fp16-weights"))
    places: dict[str, set[int]] = {}
    upcasts = {name: m for name, m in half._model.visual.named_modules() if isinstance(m, UpcastToFloat32)}
    for name, module in upcasts.items():
        module.register_forward_hook(
            lambda mod, args, out, name=name: places.setdefault(name, set()).add(out.data_ptr()))
    (arena,) = {id(m.arena): m.arena for m in upcasts.values()}.values()
    frames = [np.random.default_rng(i).integers(0, 255, (120, 160, 3), dtype=np.uint8) for i in range(3)]
    first = half.encode_images(frames)
    np.testing.assert_array_equal(half.encode_images(frames), first)  # nothing stale carried between calls
    start = arena.buffer.data_ptr()
    end = start + arena.buffer.numel() * arena.buffer.element_size()
    inside = {name for name, at in places.items() if all(start <= p < end for p in at)}
    assert set(places) == set(upcasts) and inside == set(upcasts) - {"parametrizations.proj.0"}
    assert all(len(places[name]) == 1 for name in inside)
    assert 0 < end - start <= MAX_CALL_CACHE_BYTES


def test_none_of_the_checkpoint_stays_resident_after_encoding(fp32_ckpt, tmp_path):
    """The fp32 pages are given back as each weight is converted, and the small fp32 tensors are copied out of the
    file: reading them at each forward mapped their page-cache folios again (84 MB of this 165 MB file)."""
    from pathlib import Path

    own = tmp_path / "own.pt"  # a file no other encoder of this test process maps
    own.write_bytes(Path(fp32_ckpt).read_bytes())
    enc = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=str(own), precision="fp16-weights"))
    enc.encode_images([np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)] * 2)
    assert resident_kb_of(str(own)) < 0.05 * own.stat().st_size / 1024
