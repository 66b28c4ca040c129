"""The short-lived process that does CLIP's torch work for the ONNX Runtime encoder, which never imports torch.

``import torch`` + open_clip alone cost ~730 MB of RSS on a desktop CUDA build, more than the ONNX session's
whole budget leaves. So whatever needs torch (resolving a pretrained tag, exporting the image tower the first
time, encoding query texts not yet in the cache) runs here, in ``python -m companion.vision.encoders.clip_child``:
it writes its results into the cache (``clip_cache.ClipCache``) and exits, so its memory goes back to the OS. The
caller (``clip_child_runner``) only waits for it (at start-up, or on the request worker of a query change, never on a receive loop).

The request is one JSON object on stdin; the answer one JSON line on stdout (with the child's own peak RSS, so a
bench can report it apart from the main process's); a failure is one line on stderr and exit status 1.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
import warnings
from pathlib import Path

import open_clip  # this module runs only as the child process, whose whole job is torch's
import torch
import torch.nn.functional as F

from companion.errors import MerlionError
from companion.vision.encoders.clip import load_clip
from companion.vision.encoders.clip_cache import ClipCache, cache_root
from companion.vision.encoders.clip_pixels import as_pair
from companion.vision.encoders.peak_rss import peak_rss_mb
from companion.vision.encoders.torch_runtime import configure_threads
from companion.vision.encoders.weights import ResolvedWeights, resolve_clip_weights

log = logging.getLogger(__name__)


def _export_image_tower(visual, size: tuple[int, int], dest: Path) -> None:
    """The tower as ONNX (fp32, dynamic batch), through a temporary file renamed into place (whole or absent)."""
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
