"""ImageNet-1k class index -> WordNet 3.0 noun offset, from the class list that ``timm`` ships.

The classifier's 1000 outputs are ImageNet's synsets in their standard order (``n01440764`` tench first).
``timm`` (a dependency of open-clip-torch, listed in pyproject.toml too) carries that list as
``timm/data/_info/imagenet_synsets.txt``; it is read as a plain file, without importing timm (seconds of imports).
The test checks all 1000 offsets exist in WordNet 3.0 and that the names match torchvision's class names.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

from companion.errors import MerlionError

CLASSES = 1000


def synsets_file() -> Path:
    spec = importlib.util.find_spec("timm")
    if spec is None or not spec.submodule_search_locations:
        raise MerlionError("query vocabulary: timm is not installed (pip install timm)")
    return Path(next(iter(spec.submodule_search_locations))) / "data" / "_info" / "imagenet_synsets.txt"


@functools.lru_cache(maxsize=1)
def class_offsets() -> tuple[int, ...]:
    """The WordNet noun offset of each ImageNet-1k class, by class index."""
    path = synsets_file()
    try:
        ids = path.read_text().split()
    except OSError as err:
        raise MerlionError(f"query vocabulary: cannot read {path}: {err}") from None
    if len(ids) != CLASSES or not all(i.startswith("n") and i[1:].isdigit() for i in ids):
        raise MerlionError(f"query vocabulary: {path} does not list {CLASSES} ImageNet synsets")
    return tuple(int(i[1:]) for i in ids)


@functools.lru_cache(maxsize=1)
def class_of_offset() -> dict[int, int]:
    """WordNet noun offset -> ImageNet-1k class index."""
    return {offset: index for index, offset in enumerate(class_offsets())}
