"""The short-lived process that does CLIP's torch work for the ONNX Runtime encoder, which never imports torch.

``import torch`` + open_clip alone cost ~730 MB of RSS on a desktop CUDA build, more than the ONNX session's
whole budget leaves. So whatever needs torch (resolving a pretrained tag, exporting the image tower the first
time, encoding query texts not yet in the cache) runs here, in ``python -m companion.vision.encoders.clip_child``:
it writes its results into the cache (``clip_cache.ClipCache``) and exits, so its memory goes back to the OS. The
caller only waits for it (at start-up, or on the request worker of a query change, never on a receive loop).

The request is one JSON object on stdin; the answer one JSON line on stdout (with the child's own peak RSS, so a
bench can report it apart from the main process's); a failure is one line on stderr and exit status 1.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

from companion.errors import MerlionError
from companion.vision.encoders.peak_rss import peak_rss_mb

log = logging.getLogger(__name__)


CHILD_TIMEOUT_S = 900.0
"""Longest a child may take (an export of a large tower on a slow CPU takes minutes): a hung one is killed."""


def run_clip_child(request: dict, what: str, *, timeout_s: float = CHILD_TIMEOUT_S) -> dict:
    """Run the child on ``request`` and return its answer; its one-line error becomes a MerlionError.

    ``what`` says what it was for, in the log and the error ("export the image tower", "encode 2 queries").
    """
    import companion

    env = dict(os.environ)  # the child imports this same checkout of the package, however the caller found it
    root = str(Path(companion.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
    start = time.monotonic()
    log.info("CLIP: starting a torch child process to %s", what)
    try:
        proc = subprocess.run([sys.executable, "-m", "companion.vision.encoders.clip_child"],
                              input=json.dumps(request), capture_output=True, text=True, env=env, check=False,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: the torch child process did not "
                           f"finish within {timeout_s:.0f} s and was killed") from None
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    if proc.returncode < 0:  # killed (the OOM killer, most likely): its last stderr line is not the cause
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: the torch child process was killed "
                           f"by signal {-proc.returncode} (out of memory?)")
    if proc.returncode != 0:
        reason = lines[-1].strip() if lines else f"exit status {proc.returncode}"
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: {reason}")
    answer = json.loads(proc.stdout.strip().splitlines()[-1])
    answer["seconds"] = round(time.monotonic() - start, 2)
    log.info("CLIP: child process did %s in %.1f s (its peak RSS %.0f MB, now returned)", what,
             answer["seconds"], answer["peak_rss_mb"])
    return answer


def _export_image_tower(visual, size: tuple[int, int], dest: Path) -> None:
    """The tower as ONNX (fp32, dynamic batch), through a temporary file renamed into place (whole or absent)."""
    import tempfile
    import warnings

    import torch

    dest.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="merlion-onnx-", dir=dest.parent) as tmp:
        path = Path(tmp) / "image_tower.onnx"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the TorchScript exporter announces its deprecation
            torch.onnx.export(visual, (torch.zeros(1, 3, *size),), str(path), input_names=["image"],
                              output_names=["embedding"], dynamic_axes={"image": {0: "n"}, "embedding": {0: "n"}},
                              opset_version=17, dynamo=False)
        os.replace(path, dest)


def _serve(request: dict) -> dict:
    """Resolve the weights, export the tower if asked and not cached, encode the texts not cached."""
    import open_clip
    import torch
    import torch.nn.functional as F

    from companion.vision.encoders.clip import load_clip
    from companion.vision.encoders.clip_cache import ClipCache, cache_root
    from companion.vision.encoders.clip_pixels import as_pair
    from companion.vision.encoders.torch_runtime import configure_threads
    from companion.vision.encoders.weights import ResolvedWeights, resolve_clip_weights

    configure_threads()
    model_name = request["model"]
    if request.get("resolved"):  # the caller already knows the file (and the tag's preprocessing)
        known = request["resolved"]
        weights = ResolvedWeights(path=Path(known["path"]), source=known["source"],
                                  preprocess=known.get("preprocess") or {})
    else:
        weights = resolve_clip_weights(model_name, request.get("weights"), request.get("pretrained"))
    cache = ClipCache(cache_root(request.get("cache_dir")), weights.path, model_name, weights.preprocess)
    answer: dict = {"weights": str(weights.path), "source": weights.source, "preprocess": weights.preprocess,
                    "exported": False, "encoded": 0}
    if request.get("export") and not cache.has_tower():
        model = load_clip(weights, model_name, "image")  # not in inference mode: the exporter traces it
        pcfg = open_clip.get_model_preprocess_cfg(model)
        size = as_pair(pcfg.get("size", 224))
        _export_image_tower(model.visual, size, cache.onnx_path)
        cache.write_tower_manifest({
            "model": model_name, "weights": str(weights.path),
            "preprocess": {"size": list(size), "mean": list(pcfg.get("mean") or open_clip.OPENAI_DATASET_MEAN),
                           "std": list(pcfg.get("std") or open_clip.OPENAI_DATASET_STD),
                           "interpolation": pcfg.get("interpolation", "bicubic"),
                           "resize_mode": pcfg.get("resize_mode", "shortest")},
            "dim": int(getattr(model.visual, "output_dim", 0) or 0),
            "exported_with": {"torch": torch.__version__, "open_clip": open_clip.__version__}})
        answer["exported"] = True
        del model
    texts = [t for t in dict.fromkeys(request.get("texts", [])) if t not in cache.texts([t])]
    if texts:
        with torch.inference_mode():
            model = load_clip(weights, model_name, "text")  # fp32: the reference numerics, once per query change
            tokens = open_clip.get_tokenizer(model_name)(texts)
            emb = F.normalize(model.encode_text(tokens).float(), dim=-1).numpy()
        for text, row in zip(texts, emb, strict=True):
            cache.put_text(text, row)
        answer["encoded"] = len(texts)
        # also in the answer: a cache that cannot be written (a read-only home) must not stop the queries
        answer["embeddings"] = {text: [float(v) for v in row] for text, row in zip(texts, emb, strict=True)}
    return answer


def main() -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        answer = _serve(json.loads(sys.stdin.read()))
    except MerlionError as err:
        print(str(err), file=sys.stderr)
        return 1
    except Exception as err:  # one line for the caller, whatever torch or open_clip raised
        reason = " ".join(str(err).split())[:300]
        print(f"{type(err).__name__}: {reason}", file=sys.stderr)
        return 1
    answer["peak_rss_mb"] = round(peak_rss_mb(), 1)  # VmHWM: ru_maxrss would include the parent's at the fork
    print(json.dumps(answer))
    return 0


if __name__ == "__main__":
    sys.exit(main())
