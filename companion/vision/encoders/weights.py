"""Where CLIP weights come from: a local file, or open_clip's pretrained tag when it is already in the local cache.

The vehicle has no network, so nothing here downloads at run time: ``resolve_clip_weights`` only looks in the
caches open_clip itself would fill (the Hugging Face hub cache for ``hf_hub`` tags, ``~/.cache/clip`` for URL
tags). ``pull`` is the one place that downloads, run on a machine with a network (``merlion models pull``); the
files it leaves in the cache are then found offline, or copied onto the vehicle and passed as ``--weights``.
open_clip (and with it torch) is imported only where a tag must be looked up, so a ``--weights`` file resolves in
a process that never imports torch (``runtime: onnx``).
"""

from __future__ import annotations

import logging
import os
import socket
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlparse

from huggingface_hub import constants, try_to_load_from_cache

from companion.errors import MerlionError, UsageError

log = logging.getLogger(__name__)

_HF_DEFAULT_NAMES = ("open_clip_model.safetensors", "open_clip_pytorch_model.bin")


@dataclass(frozen=True)
class ResolvedWeights:
    """A checkpoint on disk and the preprocessing its training used (from the pretrained tag, when known)."""

    path: Path
    source: str
    """Where it came from, for describe() and logs: "file" or "cache:<tag>"."""
    preprocess: dict = field(default_factory=dict)
    """Overrides of the architecture's preprocessing (mean, std, interpolation, resize_mode) the tag declares."""


def how_to_get(model: str, tag: str | None) -> str:
    """The advice every missing-weights message ends with."""
    pull = f"merlion models pull {model}" + (f" --pretrained {tag}" if tag else "")
    return f"run `{pull}` on a machine with a network (then copy the file over), or pass --weights PATH"


def pretrained_cfg(model: str, tag: str) -> dict:
    """open_clip's record for (architecture, tag); a tag it does not know is a usage error naming the valid ones."""
    import open_clip  # here, not at the top: 8.2 s with torch (measured); a --weights file resolves without it

    if model not in open_clip.list_models():
        raise UsageError(f"encoder.model: unknown open_clip architecture {model!r} "
                         f"(e.g. ViT-B-32, ViT-B-16, MobileCLIP2-S0; `merlion models list --all` lists them)")
    cfg = open_clip.get_pretrained_cfg(model, tag)
    if not cfg:
        tags = ", ".join(open_clip.list_pretrained_tags_by_model(model)) or "none"
        raise UsageError(f"encoder.pretrained: {model} has no pretrained tag {tag!r} (known: {tags})")
    return cfg


def _preprocess_overrides(cfg: dict) -> dict:
    keys = ("mean", "std", "interpolation", "resize_mode")
    return {k: cfg[k] for k in keys if cfg.get(k) is not None}


def cached_checkpoint(model: str, tag: str) -> Path | None:
    """The tag's checkpoint if open_clip's caches already hold it, else None. Never touches the network."""
    cfg = pretrained_cfg(model, tag)
    hub = cfg.get("hf_hub", "")
    if hub:
        repo_id, filename = os.path.split(hub)
        names = (filename,) if filename else _HF_DEFAULT_NAMES
        if filename.endswith((".bin", ".pth")):
            names = (filename[:-4] + ".safetensors", filename)
        for name in names:
            found = try_to_load_from_cache(repo_id, name)
            if isinstance(found, str) and Path(found).is_file():
                return Path(found)
    url = cfg.get("url", "")
    if url:
        candidate = Path("~/.cache/clip").expanduser() / os.path.basename(url)
        if candidate.is_file():
            return candidate
    return None


def resolve_clip_weights(model: str, weights: str | None, tag: str | None) -> ResolvedWeights:
    """The checkpoint to load, offline: ``weights`` (a file, or an open_clip model folder) wins over the tag.

    Raises MerlionError with one line saying how to get weights when neither is available.
    """
    if weights:
        path = Path(weights).expanduser()
        if not path.exists():
            raise UsageError(f"CLIP weights {path}: no such file; {how_to_get(model, tag)}")
        return ResolvedWeights(path=path, source="file")
    if not tag:
        raise UsageError(f"no CLIP weights for {model}: encoder.weights and encoder.pretrained are both unset; "
                           f"{how_to_get(model, None)}")
    cfg = pretrained_cfg(model, tag)
    path = cached_checkpoint(model, tag)
    if path is None:
        raise UsageError(f"no CLIP weights for {model} ({tag}) in the local cache; {how_to_get(model, tag)}")
    return ResolvedWeights(path=path, source=f"cache:{tag}", preprocess=_preprocess_overrides(cfg))


def caches_hold_checkpoints() -> bool:
    """Whether either cache open_clip fills holds anything at all: a look at two folders, no open_clip import."""
    hub = Path(constants.HF_HUB_CACHE)
    if hub.is_dir() and any(entry.name.startswith("models--") for entry in hub.iterdir()):
        return True
    clip_dir = Path("~/.cache/clip").expanduser()
    return clip_dir.is_dir() and any(entry.is_file() for entry in clip_dir.iterdir())


def clip_weights_available(model: str, weights: str | None, tag: str | None, *,
                           quick: bool = True) -> tuple[bool, str]:
    """Whether CLIP could load offline, and why not (the reason ``auto`` logs when it falls back).

    ``quick``: with no file given and both caches empty the answer is no without importing open_clip (2.3 s with
    torch and torchvision, measured), which every ``auto`` start on a machine without CLIP weights would pay; the
    model and tag are then not checked against open_clip's lists (``quick=False`` checks them)."""
    if quick and not weights and tag and not caches_hold_checkpoints():
        return False, f"no CLIP weights for {model} ({tag}) in the local cache; {how_to_get(model, tag)}"
    try:
        resolve_clip_weights(model, weights, tag)
    except MerlionError as err:
        return False, str(err)
    return True, ""


def list_cached() -> list[tuple[str, str, Path]]:
    """Every (architecture, tag, file) open_clip knows whose checkpoint is already cached locally."""
    import open_clip  # 8.2 s with torch (measured): only when the cache is listed

    out = []
    for model, tag in open_clip.list_pretrained():
        try:
            path = cached_checkpoint(model, tag)
        except MerlionError:
            continue
        if path is not None:
            out.append((model, tag, path))
    return out


def _download_host(cfg: dict) -> tuple[str, int]:
    """(host, port) the download will contact: the Hugging Face endpoint (HF_ENDPOINT honoured) or the URL's."""
    if cfg.get("hf_hub"):
        url = urlparse(constants.ENDPOINT)
    else:
        url = urlparse(cfg.get("url", ""))
    return url.hostname or "", url.port or (80 if url.scheme == "http" else 443)


def _check_reachable(where: tuple[str, int], model: str, tag: str, timeout_s: float = 5.0) -> None:
    """Fail in seconds, with one line, where there is no network (the hub client would retry for a minute)."""
    host, port = where
    if not host:
        raise MerlionError(f"{model} ({tag}) has no download location in open_clip")
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise MerlionError(f"cannot download {model} ({tag}): no network ({host}: {reason}); on a machine with a "
                           f"network run `merlion models pull {model} --pretrained {tag}`, copy the file over "
                           f"and pass --weights PATH") from None


def pull(model: str, tag: str, cache_dir: str | None = None) -> Path:
    """Download a tag's checkpoint into open_clip's cache, verify it loads into the architecture, return its path.

    open_clip checks the SHA-256 of URL checkpoints; loading the state dict into the architecture verifies the
    rest (a truncated or wrong file fails there). No network: a one-line MerlionError, not a traceback.
    """
    import open_clip  # 8.2 s with torch (measured): only for a download

    cfg = pretrained_cfg(model, tag)
    _check_reachable(_download_host(cfg), model, tag)
    log.info("downloading %s (%s) ...", model, tag)
    logging.getLogger("huggingface_hub").setLevel(logging.ERROR)  # its per-retry warnings repeat our one line
    try:
        path = Path(open_clip.download_pretrained(cfg, cache_dir=cache_dir))
    except Exception as err:  # hub, urllib and OS errors all mean the same thing to the user
        reason = " ".join(str(err).split())[:200] or type(err).__name__
        raise MerlionError(f"cannot download {model} ({tag}): {reason}; with no network here, copy a checkpoint "
                           f"over and pass --weights PATH") from None
    if not path.is_file():
        raise MerlionError(f"cannot download {model} ({tag}): open_clip returned no file")
    try:
        open_clip.create_model(model, pretrained=str(path), device="cpu")
    except Exception as err:
        raise MerlionError(f"downloaded {path} but it does not load into {model}: {err}") from None
    return path
