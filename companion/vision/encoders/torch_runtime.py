"""Where and at what precision the torch encoders run: device, dtype and thread choices made in one place.

Both torch encoders (CLIP and the packaged EfficientNet) need the same decisions, and the reasons behind them
(bf16 only where the CPU has native bf16 units, fp16 on CUDA, few threads on a two-core companion) should be
written down once.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from companion.errors import UsageError
from companion.vision.encoders.cpu_threads import intra_op_threads

log = logging.getLogger(__name__)

PRECISIONS = {"fp32": torch.float32, "fp16-weights": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16,
              "int8": torch.float32}
"""Each explicit precision and the dtype its layers compute in (int8 and fp16-weights only store in less)."""
_threads_set = False


def cpu_has_native_bf16(cpuinfo: str | None = None) -> bool:
    """True on CPUs with AMX or AVX512-BF16, where bf16 matmuls run faster than fp32 instead of emulated."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
        except OSError:
            return False
    for line in cpuinfo.splitlines():
        if line.startswith(("flags", "Features")):
            flags = set(line.split(":", 1)[-1].split())
            return bool(flags & {"amx_bf16", "avx512_bf16"})
    return False


def pick_device(device: str) -> torch.device:
    """auto: CUDA when present, else CPU; asking for CUDA where there is none is a user error."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise UsageError("encoder.device: cuda asked for but torch sees no CUDA device (use auto or cpu)")
    return torch.device(device)


def pick_precision(precision: str, device: torch.device) -> str:
    """What ``auto`` means where the encoder runs; an explicit precision is checked against the device.

    auto: fp16 on CUDA; on the CPU bf16 where it has native bf16 units, else ``fp16-weights`` (fp32 arithmetic
    on weights stored in fp16: about fp32's speed and near its numerics in half the tower's memory; plain fp32 would
    put ViT-B-32 over the 1 GB budget, and emulated bf16 is slower than fp32).
    """
    if precision == "auto":
        if device.type == "cuda":
            return "fp16"
        return "bf16" if cpu_has_native_bf16() else "fp16-weights"
    if precision not in PRECISIONS:
        raise UsageError(f"encoder.precision: unknown value {precision!r} ({', '.join(('auto', *PRECISIONS))})")
    if precision in ("int8", "fp16-weights") and device.type != "cpu":
        raise UsageError(f"encoder.precision: {precision} runs on the CPU only (use fp16 on CUDA)")
    return precision


def compute_dtype(precision: str) -> torch.dtype:
    """The dtype the layers compute in (and the frames are fed in) for a precision ``pick_precision`` returned."""
    return PRECISIONS[precision]


def padded_to(batch: torch.Tensor, size: int) -> torch.Tensor:
    """On CUDA, a short batch padded (with copies of its last frame) to ``size``, so one shape is ever run.

    The frame gate makes batches of 1 to ``encoder.batch`` frames, and every new shape makes cuDNN and cuBLAS
    choose and build kernels again. On an H100 (`merlion bench pipeline`, survey video, gated) the packaged
    encoder's stage took 179 ms per frame before and 5.3 ms after (video 17 -> 497 frames/s; that host's 16
    CPU cores: 100-112), CLIP ViT-B-32 in fp16 12.2 -> 8.6 ms. The CPU keeps the short batch.
    """
    if batch.device.type != "cuda" or batch.shape[0] >= size:
        return batch
    return torch.cat([batch, batch[-1:].expand(size - batch.shape[0], *batch.shape[1:])])


def configure_threads() -> None:
    """One intra-op thread per core (or as many as ``OMP_NUM_THREADS`` sets) and a single inter-op thread (on a
    2-core companion more only thrashes); denormals flushed to zero, which costs inference nothing in accuracy."""
    global _threads_set
    if _threads_set:
        return
    torch.set_num_threads(max(1, intra_op_threads()))
    torch.set_flush_denormal(True)  # tiny activations otherwise take the slow microcode path on x86
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:
        pass  # already set once parallel work started; the intra-op setting is the one that matters
    _threads_set = True
