"""fp32 arithmetic on weights kept in fp16: half the image tower's memory at about fp32's speed, for CPUs without bf16.

On an AVX2-only CPU the reduced-precision paths do not pay: bf16 is emulated (about 2x slower than fp32) and int8
reaches 1.1-1.4x, while fp32 holds ViT-B-32's image tower in 351 MB, which with torch's and open_clip's imports
(~670 MB) puts the companion over its 1 GB budget. Here each large weight is stored in fp16 and upcast to fp32
when its layer runs (a ``torch.nn.utils.parametrize`` parametrization, so every module type keeps its own forward,
nn.MultiheadAttention's fused in-projection included). Only the storage rounds: activations, accumulations,
LayerNorm and softmax stay fp32. The upcasts are one layer's weights at a time (~9 MB for ViT-B-32), written into
one buffer that every call reuses.

fp16 keeps 11 significant bits, bf16 only 8: CLIP checkpoints trained in mixed precision (OpenAI's were released
in fp16) lose nothing, others a relative 2^-12 per weight. A tensor that fp16 cannot hold (a value beyond its
range, or a relative error above ``MAX_RELATIVE_ERROR`` from values in its subnormal range) stays in fp32.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import Iterator
from pathlib import Path

import torch
from torch.nn.utils import parametrize

from companion.vision.encoders.mapped_cast import FilePages, module_tensors

log = logging.getLogger(__name__)

MIN_ELEMENTS = 65536
"""Smaller tensors (biases, LayerNorm, class token) stay fp32: upcasting them on every call would cost more time
than their memory is worth."""

CHUNK = 1 << 20
"""Elements converted at a time."""

MAX_RELATIVE_ERROR = 1e-3
"""Largest ||w16 - w|| / ||w|| kept in fp16 (fp16's rounding alone gives ~3e-4 at most)."""


MAX_CALL_CACHE_BYTES = 32 << 20
"""Most fp32 bytes of upcast weights one module call may hold at once (an attention layer of ViT-L is 16 MB)."""


class UpcastArena:
    """One fp32 buffer, allocated once, that the upcasts of a module call are written into.

    An upcast allocated afresh each time (ViT-B-32: 48 tensors of 2-9 MB per forward) costs a page-faulted
    allocation and its zeroing every time; writing into warm memory made a forward 3-5% faster. A view handed out
    here lives until the outermost module call that opened a scope returns, which is when ``parametrize.cached``
    (which holds these views) forgets it; only then is the buffer reused. A read outside any scope, or one that
    does not fit, gets an ordinary tensor.
    """

    def __init__(self) -> None:
        self.buffer = torch.empty(0)
        self.top = 0
        self.depth = 0

    def reserve(self, elements: int) -> None:
        """Room for one scope's upcasts (the largest scope's, as each is registered)."""
        if elements > self.buffer.numel():
            self.buffer = torch.empty(elements)

    @contextlib.contextmanager
    def scope(self) -> Iterator[None]:
        """One module call; the buffer is free again when the outermost scope closes."""
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1
            if self.depth == 0:
                self.top = 0

    def take(self, stored: torch.Tensor) -> torch.Tensor:
        n = stored.numel()
        if self.depth == 0 or self.top + n > self.buffer.numel():
            return stored.float()  # outside any scope (read once), or a scope larger than reserved
        out = self.buffer[self.top:self.top + n].view(stored.shape)
        self.top += n
        return out.copy_(stored)  # (no autograd here: the encoder runs under inference_mode)


class UpcastToFloat32(torch.nn.Module):
    """The parametrization: the stored fp16 tensor as the fp32 one the layer computes with."""

    def __init__(self, arena: UpcastArena) -> None:
        super().__init__()
        self.arena = arena

    def forward(self, stored: torch.Tensor) -> torch.Tensor:
        return self.arena.take(stored)


def _to_fp16(weight: torch.Tensor) -> torch.Tensor | None:
    """``weight`` in fp16, or None where fp16 cannot hold it. Converted and checked a slice at a time, so the
    load's transient is a few MB, not two fp32 copies of the largest tensor."""
    half = torch.empty(weight.shape, dtype=torch.float16)
    src, dst = weight.reshape(-1), half.view(-1)
    err = norm = 0.0
    for start in range(0, src.numel(), CHUNK):
        part = src[start:start + CHUNK].float()
        dst[start:start + CHUNK].copy_(part)
        back = dst[start:start + CHUNK].float()
        if not torch.isfinite(back).all():
            return None
        err += float(torch.linalg.vector_norm(back - part)) ** 2
        norm += float(torch.linalg.vector_norm(part)) ** 2
    return half if err <= (MAX_RELATIVE_ERROR ** 2) * norm else None


def store_weights_in_fp16(module: torch.nn.Module, checkpoint: Path | None = None) -> int:
    """Keep ``module``'s large parameters in fp16, computed with in fp32; every other float tensor becomes fp32.
    Returns the bytes saved over fp32.

    The pages of a memory-mapped ``checkpoint`` each tensor was read from are given back as it is converted, so
    the load peak is the fp16 tower plus one tensor. A checkpoint saved in fp16 is taken as it is. The tensors
    left in fp32 (biases, LayerNorm) are copied out of the file too: the page cache holds a file in large folios,
    and reading one small tensor at each forward mapped its whole folio, i.e. megabytes of the weights around it
    (84 MB of a 165 MB checkpoint were resident again after two frames).
    """
    pages = FilePages(checkpoint)
    arena = UpcastArena()
    saved = kept = 0
    with torch.no_grad():
        for owner, name, tensor, is_param in module_tensors(module):
            if not tensor.is_floating_point():
                continue
            old = tensor.data
            large = is_param and old.numel() >= MIN_ELEMENTS
            half = (old if old.dtype == torch.float16 else _to_fp16(old)) if large else None
            if half is not None:
                pages.replace(tensor, half)  # (an fp16 checkpoint's tensor stays where it is, in the file)
                parametrize.register_parametrization(owner, name, UpcastToFloat32(arena), unsafe=True)
                saved += half.numel() * 2
            else:
                kept += int(large)  # a large weight out of fp16's reach
                pages.replace(tensor, old.to(torch.float32, copy=True))  # a copy, out of the file: see above
            del old
    for owner in list(module.modules()):
        if not parametrize.is_parametrized(owner):
            continue
        upcast = _upcast_bytes(owner)
        if upcast <= MAX_CALL_CACHE_BYTES:
            _upcast_once_per_call(owner, arena)
            arena.reserve(upcast // 4)
    log.debug("fp16 storage: %d MB saved, %d tensors kept in fp32 (out of fp16's reach)", saved >> 20, kept)
    return saved


def _upcast_bytes(module: torch.nn.Module) -> int:
    """fp32 bytes of the fp16-stored tensors in ``module`` and below."""
    return sum(4 * owner.parametrizations[name].original.numel()
               for owner in module.modules() if parametrize.is_parametrized(owner)
               for name in owner.parametrizations)


def _upcast_once_per_call(module: torch.nn.Module, arena: UpcastArena) -> None:
    """Within one call of ``module``, each fp16-stored weight read during it is upcast once, then dropped.

    A parametrized tensor is recomputed at every attribute read, and nn.MultiheadAttention reads its in- and
    out-projection weights several times per call (its fast-path checks, then the kernel): ViT-B-32 upcast
    687 MB of weights per forward instead of 352 (the upcasts are ~13% of a forward's CPU time).
    ``parametrize.cached`` holds each upcast until the call returns, so only modules whose weights are small
    (``MAX_CALL_CACHE_BYTES``, an attention layer, not the whole tower that owns the final projection) get it.
    Its cache is process-wide: the encoder's callers serialise their calls (the live companion holds one lock
    around the shared encoder), so two forwards never share it.
    """
    forward = module.forward

    @functools.wraps(forward)
    def forward_upcasting_once(*args, **kwargs):
        with arena.scope(), parametrize.cached():
            return forward(*args, **kwargs)

    module.forward = forward_upcasting_once


def stored_in_fp16(module: torch.nn.Module) -> list[str]:
    """Names of the parameters ``module`` keeps in fp16 storage (what the tests and ``describe`` look at)."""
    names = []
    for owner_name, owner in module.named_modules():
        if parametrize.is_parametrized(owner):
            for name in owner.parametrizations:
                if owner.parametrizations[name].original.dtype == torch.float16:
                    names.append(f"{owner_name}.{name}" if owner_name else name)
    return names
