"""Cast a model whose tensors live in a memory-mapped checkpoint to another dtype without holding both copies.

``model.to(bfloat16)`` reads every fp32 page of the mapped file (they stay resident, and counted in RSS, until the
last tensor of the mapping is gone) while it builds the bf16 copies: ViT-B-32's image tower peaked at its 351 MB
of fp32 pages + 175 MB of bf16 ones, ~300 MB above the steady level. Here each tensor is cast in turn and the
file pages it was read from are dropped from the process at once (``madvise(MADV_DONTNEED)``: clean private file
pages, so the page cache keeps them and a later read would simply fault them in again), so the peak is the bf16
copy plus one tensor. Only ranges inside the checkpoint's own mapping (``/proc/self/maps``) are ever touched:
dropping an anonymous page would lose data.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import mmap
import os
from collections.abc import Iterator
from pathlib import Path

import torch

log = logging.getLogger(__name__)

_MADV_DONTNEED = 4  # Linux


def _mapped_ranges(path: Path) -> list[tuple[int, int]]:
    """Address ranges of this process's mappings of ``path`` (empty where /proc is missing)."""
    target = os.path.realpath(path)
    ranges = []
    try:
        with open("/proc/self/maps", encoding="utf-8") as maps:
            for line in maps:
                parts = line.split(maxsplit=5)
                if len(parts) == 6 and os.path.realpath(parts[5].strip()) == target:
                    start, end = (int(x, 16) for x in parts[0].split("-"))
                    ranges.append((start, end))
    except OSError:
        return []
    return ranges


def module_tensors(model: torch.nn.Module) -> Iterator[tuple[torch.nn.Module, str, torch.Tensor, bool]]:
    """Every parameter and buffer of ``model`` and its submodules: (owner, name, tensor, is a parameter).

    Listed before anything is yielded, so a caller may replace tensors (or parametrize them) as it goes.
    """
    found = [(owner, name, tensor, store is owner._parameters)
             for owner in model.modules() for store in (owner._parameters, owner._buffers)
             for name, tensor in store.items() if tensor is not None]
    yield from found


class FilePages:
    """The checkpoint's mappings in this process, and the means to give a tensor's pages in them back.

    ``path`` None (a checkpoint that is not memory-mapped): nothing is ever dropped.
    """

    def __init__(self, path: Path | None) -> None:
        self.ranges = _mapped_ranges(path) if path is not None else []
        name = ctypes.util.find_library("c")
        self._madvise = ctypes.CDLL(name, use_errno=True).madvise if name and self.ranges else None
        if self._madvise is not None:
            self._madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
        self.dropped = 0

    def drop(self, tensor: torch.Tensor) -> None:
        """Drop the whole pages of ``tensor``'s bytes that lie inside the checkpoint's mapping."""
        if self._madvise is None or tensor.device.type != "cpu":
            return
        begin = tensor.data_ptr()
        end = begin + tensor.numel() * tensor.element_size()
        page = mmap.PAGESIZE
        for lo, hi in self.ranges:
            a, b = max(begin, lo), min(end, hi)
            a = (a + page - 1) // page * page  # whole pages only: a page shared with a neighbour is kept
            b = b // page * page
            if b > a and self._madvise(a, b - a, _MADV_DONTNEED) == 0:
                self.dropped += b - a

    def replace(self, tensor: torch.Tensor, new: torch.Tensor) -> None:
        """``tensor.data = new``, then give back the pages of the bytes it held (unless ``new`` still uses them)."""
        old = tensor.data
        tensor.data = new
        if new.data_ptr() != old.data_ptr():
            self.drop(old)


def cast_dropping_file_pages(model: torch.nn.Module, dtype: torch.dtype, checkpoint: Path) -> torch.nn.Module:
    """``model.to(dtype)`` for floating tensors, one at a time, giving back each one's mapped file pages."""
    dropper = FilePages(checkpoint)
    with torch.no_grad():
        for _owner, _name, tensor, _is_param in module_tensors(model):
            if tensor.is_floating_point() and tensor.dtype != dtype:
                dropper.replace(tensor, tensor.data.to(dtype))
    log.debug("cast to %s, %d MB of %s's pages given back", dtype, dropper.dropped >> 20, checkpoint)
    return model


def drop_file_pages(checkpoint: Path) -> int:
    """Give back every resident page of this process's mappings of ``checkpoint``; returns the bytes dropped.

    For when the model no longer reads the file (an int8 tower holds its own packed copies) but some small tensor
    still keeps the mapping alive: its pages would fault back in from the page cache if ever read again.
    """
    dropper = FilePages(checkpoint)
    if dropper._madvise is not None:
        for lo, hi in dropper.ranges:
            if dropper._madvise(lo, hi - lo, _MADV_DONTNEED) == 0:
                dropper.dropped += hi - lo
    return dropper.dropped
