"""Where and at what precision the torch encoders run: device, dtype and thread choices made in one place.

Both torch encoders (CLIP and the packaged EfficientNet) need the same decisions, and the reasons behind them
(bf16 only where the CPU has native bf16 units, fp16 on CUDA, few threads on a two-core companion) should be
written down once.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch

from companion.errors import UsageError

log = logging.getLogger(__name__)

_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16}
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


def pick_dtype(precision: str, device: torch.device) -> torch.dtype:
    """auto: fp16 on CUDA, bf16 on CPUs with native bf16, fp32 elsewhere (emulated bf16 is slower than fp32)."""
    if precision == "auto":
        if device.type == "cuda":
            return torch.float16
        return torch.bfloat16 if cpu_has_native_bf16() else torch.float32
    try:
        return _DTYPES[precision]
    except KeyError:
        raise UsageError(f"encoder.precision: unknown value {precision!r} (auto, fp32, bf16, fp16)") from None


def dtype_name(dtype: torch.dtype) -> str:
    return {v: k for k, v in _DTYPES.items()}[dtype]


def configure_threads() -> None:
    """One intra-op thread per core and a single inter-op thread (on a 2-core companion more only thrashes);
    denormals flushed to zero, which costs inference nothing in accuracy."""
    global _threads_set
    if _threads_set:
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    torch.set_num_threads(max(1, cores))
    torch.set_flush_denormal(True)  # tiny activations otherwise take the slow microcode path on x86
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:
        pass  # already set once parallel work started; the intra-op setting is the one that matters
    _threads_set = True
