"""The paper's encoder: an open_clip model (any architecture, ViT-B-32 by default) with weights found offline.

Scores follow REFERENCE.md exactly: L2-normalised embeddings, softmax of 100 x cosine over [positive, negatives],
the positive's share (the fixed scale 100, not the model's learned logit scale). Preprocessing is read from the
loaded model (size, mean/std, interpolation, resize mode), so it is always the one its weights were trained with;
it runs in torch on uint8 frames (faster than PIL), and a test holds it to open_clip's own transform.

This is ``runtime: torch``, and the loader the torch child process (``clip_child``) shares; ``runtime: onnx`` is
``onnx_clip.OnnxClipEncoder``, which never imports torch. Query embeddings come from ``clip_texts`` in both.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import open_clip
import torch
import torch.nn.functional as F
from open_clip import factory as open_clip_factory
from PIL import Image
from torch.ao.quantization import quantize_dynamic

from companion.config import EncoderConfig
from companion.errors import MerlionError, UsageError
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.clip_cache import ClipCache, cache_root
from companion.vision.encoders.clip_pixels import as_pair, resize_shape
from companion.vision.encoders.clip_scores import positive_share
from companion.vision.encoders.clip_texts import TextEmbeddings
from companion.vision.encoders.half_weights import store_weights_in_fp16
from companion.vision.encoders.heap_trim import release_freed_memory
from companion.vision.encoders.mapped_cast import (
    FilePages,
    cast_dropping_file_pages,
    drop_file_pages,
    module_tensors,
)
from companion.vision.encoders.torch_runtime import (
    compute_dtype,
    configure_threads,
    padded_to,
    pick_device,
    pick_precision,
)
from companion.vision.encoders.weights import ResolvedWeights, resolve_clip_weights

log = logging.getLogger(__name__)



class _DropRandomInitWarning(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "initialized randomly" not in record.getMessage()


def read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """A checkpoint's tensors, memory-mapped when the file is in torch's zip format (else read whole)."""
    try:
        ckpt = torch.load(path, map_location="cpu", mmap=True, weights_only=True)
    except RuntimeError as err:
        if "mmap" not in str(err) and "zip" not in str(err):
            raise
        ckpt = torch.load(path, map_location="cpu", weights_only=True)  # legacy (pre-1.6) format
    if isinstance(ckpt, dict) and "state_dict" in ckpt:
        ckpt = ckpt["state_dict"]
    if not isinstance(ckpt, dict) or not ckpt:
        raise ValueError("not a state dict")
    if next(iter(ckpt)).startswith("module."):
        ckpt = {k[len("module."):]: v for k, v in ckpt.items()}
    return dict(ckpt)


def quantize_image_tower(visual: torch.nn.Module, checkpoint: Path | None = None) -> torch.nn.Module:
    """int8 weights and dynamically quantized activations for the image tower's nn.Linear layers (fbgemm/x86).

    On CPUs without bf16 units this is the one reduced precision that is faster than fp32; attention's fused
    in-projection stays fp32 (nn.MultiheadAttention keeps its own weights), as does the text tower, which runs
    once per query change. Scores stay within 0.01 of fp32 (tested). Layer group by layer group, so that the
    fp32 pages of a memory-mapped ``checkpoint`` each group was packed from are given back at once (the load
    peak is the int8 tower plus one group, not plus the whole fp32 tower).
    """

    pages = FilePages(checkpoint)
    parents = [m for m in visual.modules() if any(isinstance(c, torch.nn.Linear) for c in m.children())]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch announces the move of eager quantization to torchao
        for parent in parents:
            packed_from = [c.weight.data for c in parent.children() if isinstance(c, torch.nn.Linear)]
            quantize_dynamic(parent, {torch.nn.Linear}, dtype=torch.qint8, inplace=True)
            for weight in packed_from:
                pages.drop(weight)
    return visual


TEXT_TOWER = ("transformer", "token_embedding", "positional_embedding", "ln_final", "text_projection", "attn_mask",
              "text")
"""The attributes of an open_clip model that make up its text tower (``text`` in CustomTextCLIP)."""


def drop_text_tower(model: torch.nn.Module) -> None:
    """Free the text tower: it runs once per query change and would otherwise hold ~254 MB (ViT-B-32 fp32)."""
    for name in TEXT_TOWER:
        if hasattr(model, name):
            delattr(model, name)


def detach_from_file(model: torch.nn.Module) -> None:
    """Copy what is left of a memory-mapped model into ordinary memory.

    All tensors of a memory-mapped checkpoint share one mapping: while one small tensor (logit_scale) lives, the
    pages the dropped towers once touched stay mapped and counted in RSS.
    """
    for _owner, _name, tensor, _is_param in module_tensors(model):
        tensor.data = tensor.data.clone()


def _causal_mask(n: int) -> torch.Tensor:
    """open_clip's text attention mask (a non-persistent buffer, so not in the checkpoint)."""
    return torch.empty(n, n).fill_(float("-inf")).triu_(1)


class ClipPreprocess:
    """open_clip's eval transform, done in torch on BGR uint8 arrays.

    Matches torchvision's Resize (shortest side, output rounded like PIL to uint8) + CenterCrop + Normalize for
    the "shortest" and "squash" modes; other modes fall back to open_clip's own PIL transform.
    """

    def __init__(self, cfg: dict) -> None:
        self.size = as_pair(cfg.get("size", 224))
        self.mode = cfg.get("resize_mode", "shortest")
        self.interpolation = cfg.get("interpolation", "bicubic")
        self.mean = torch.tensor(cfg.get("mean", open_clip.OPENAI_DATASET_MEAN), dtype=torch.float32).view(3, 1, 1)
        self.std = torch.tensor(cfg.get("std", open_clip.OPENAI_DATASET_STD), dtype=torch.float32).view(3, 1, 1)
        self._fallback = None
        square = self.size[0] == self.size[1]
        if self.mode not in ("shortest", "squash") or (self.mode == "shortest" and not square):
            self._fallback = open_clip.image_transform(self.size, is_train=False, mean=tuple(self.mean.flatten()),
                                                       std=tuple(self.std.flatten()), resize_mode=self.mode,
                                                       interpolation=self.interpolation)

    def reference(self, bgr: np.ndarray) -> torch.Tensor:
        """open_clip's own PIL transform for the same settings (the yardstick the tests compare against)."""
        transform = self._fallback or open_clip.image_transform(
            self.size, is_train=False, mean=tuple(self.mean.flatten().tolist()),
            std=tuple(self.std.flatten().tolist()), resize_mode=self.mode, interpolation=self.interpolation)
        return transform(Image.fromarray(np.ascontiguousarray(bgr[:, :, ::-1])))

    def __call__(self, bgr: np.ndarray) -> torch.Tensor:
        """BGR uint8 (H, W, 3) -> normalised float32 (3, h, w)."""
        if self._fallback is not None:
            return self.reference(bgr)
        x = torch.from_numpy(np.ascontiguousarray(bgr[:, :, ::-1])).permute(2, 0, 1).float()[None]
        h, w = bgr.shape[:2]
        th, tw = self.size
        new_h, new_w = resize_shape(h, w, self.size, self.mode)
        if (new_h, new_w) != (h, w):
            x = F.interpolate(x, size=(new_h, new_w), mode=self.interpolation, align_corners=False,
                              antialias=True)
            x = x.clamp_(0, 255).round_()  # PIL resizes to uint8: keep the same rounding
        top = int(round((new_h - th) / 2.0))
        left = int(round((new_w - tw) / 2.0))
        x = x[0, :, top:top + th, left:left + tw]
        return (x / 255.0 - self.mean) / self.std


def load_clip(weights: ResolvedWeights, model_name: str, tower: str, device: torch.device | None = None,
              precision: str = "fp32") -> torch.nn.Module:
    """The model with one tower only ("image" or "text"), at a precision ``pick_precision`` returned; the other
    tower is dropped before it is ever read.

    The image model lives as long as a torch encoder; a text model is loaded only by the child process that
    encodes queries missing from the cache (``clip_child``), so the text tower's ~254 MB (ViT-B-32 fp32) is never
    resident beside the running image tower. A file that does not load is a one-line MerlionError.
    """
    path = weights.path
    try:
        if path.is_dir() or path.suffix in (".npz", ".npy", ".safetensors"):
            model = _load_via_open_clip(weights, model_name)
        else:
            model = _load_lean(weights, model_name)
    except Exception as err:  # torch/open_clip raise many kinds for a bad or mismatched file
        reason = " ".join(str(err).split())[:160]
        raise MerlionError(f"CLIP weights {path} do not load into {model_name}: {reason}") from None
    if tower == "image":
        drop_text_tower(model)
    else:
        del model.visual
    device = device or torch.device("cpu")
    dtype = compute_dtype(precision)
    if precision == "fp16-weights":  # each fp32 tensor's mapped pages given back as its fp16 copy is made
        store_weights_in_fp16(model.eval(), path)  # (CPU only: pick_precision refuses it on CUDA)
        release_freed_memory()  # the conversion's freed slices, left in the C heap
    elif device.type == "cpu" and dtype != torch.float32:  # never both the mapped fp32 pages and the cast copy
        model = cast_dropping_file_pages(model.eval(), dtype, path)
    else:
        model = model.eval().to(device=device, dtype=dtype)
    if precision == "int8" and tower == "image":
        for module in model.visual.modules():  # the packed int8 layers keep the fp32 bias tensor itself: a view
            if isinstance(module, torch.nn.Linear) and module.bias is not None:  # of the file would pin it
                module.bias.data = module.bias.data.clone()
        model.visual = quantize_image_tower(model.visual, path)
        detach_from_file(model)  # the fp32 tower's mapped pages go with the mapping
        release_freed_memory()
        drop_file_pages(path)  # whatever still maps the file (nothing, once the above is done) keeps no pages
    return model


def _load_via_open_clip(weights: ResolvedWeights, model_name: str) -> torch.nn.Module:
    """open_clip's own loader (Hugging Face folders, big_vision .npz, safetensors): holds two copies at peak."""
    path = weights.path
    name = f"local-dir:{path}" if path.is_dir() else model_name
    kwargs: dict = {"device": "cpu", "precision": "fp32"}
    if not path.is_dir():
        kwargs["pretrained"] = str(path)
    if weights.preprocess:
        kwargs["force_preprocess_cfg"] = weights.preprocess
    return open_clip.create_model(name, pretrained_text=False, **kwargs)


def _load_lean(weights: ResolvedWeights, model_name: str) -> torch.nn.Module:
    """One copy of the weights at peak: the checkpoint is memory-mapped and its tensors become the model's.

    open_clip's loader reads the whole checkpoint into memory and copies it into a freshly built model, so
    ViT-B-32 fp32 peaked at ~1.9 GB. Here the file's pages are mapped (read on first use, shared with the
    page cache) and ``assign=True`` hands them to the model, freeing the random initial weights.
    """
    kwargs: dict = {"device": "meta", "precision": "fp32"}
    if weights.preprocess:
        kwargs["force_preprocess_cfg"] = weights.preprocess
    quiet = _DropRandomInitWarning()
    logging.getLogger().addFilter(quiet)  # open_clip warns "initialized randomly": the weights come next
    try:  # on the meta device: no random initial weights are ever allocated (~600 MB for ViT-B-32)
        with torch.device("meta"):
            model = open_clip.create_model(model_name, pretrained=None, pretrained_text=False, **kwargs)
    finally:
        logging.getLogger().removeFilter(quiet)
    state = read_state_dict(weights.path)
    state = open_clip_factory.convert_state_dict(model, state)
    if "positional_embedding" in state and not hasattr(model, "positional_embedding"):
        state = open_clip_factory.convert_to_custom_text_state_dict(state)
    for key in ("logit_scale", "logit_bias"):
        mine = getattr(model, key, None)
        if key in state and mine is not None and mine.ndim != state[key].ndim:
            state[key] = state[key].reshape(mine.shape)
    if "logit_bias" not in state and getattr(model, "logit_bias", None) is not None:
        state["logit_bias"] = torch.zeros_like(state["logit_scale"])
    state.pop("text.transformer.embeddings.position_ids", None)
    open_clip_factory.resize_pos_embed(state, model)
    open_clip_factory.resize_text_pos_embed(state, model)
    model.load_state_dict(state, strict=True, assign=True)
    for module in model.modules():  # non-persistent buffers are not in the file: build them for real
        for key, buf in list(module._buffers.items()):
            if buf is not None and buf.is_meta:
                if key != "attn_mask":
                    raise ValueError(f"buffer {key} is not in the checkpoint")
                module._buffers[key] = _causal_mask(buf.shape[0])
    return model


class ClipEncoder(Encoder):
    """Image and text towers of an open_clip model at the configured precision, batched, in inference mode.

    ``runtime: onnx`` is another class (``onnx_clip.OnnxClipEncoder``, which ``make_encoder`` picks): it runs
    without torch in the process.
    """

    def __init__(self, cfg: EncoderConfig, *, resolved: ResolvedWeights | None = None) -> None:
        if cfg.runtime != "torch":
            raise ValueError("ClipEncoder runs torch; make_encoder builds runtime onnx's OnnxClipEncoder")
        if cfg.providers:
            raise UsageError("encoder.providers: set only with encoder.runtime onnx")
        configure_threads()
        self.name = f"clip:{cfg.model}"
        self._cfg = cfg
        self._weights = resolved or resolve_clip_weights(cfg.model, cfg.weights, cfg.pretrained)
        self._device = pick_device(cfg.device)
        self._precision = pick_precision(cfg.precision, self._device)
        self._dtype = compute_dtype(self._precision)
        self._model = self._load("image")
        pcfg = open_clip.get_model_preprocess_cfg(self._model)
        self._dim = int(getattr(self._model.visual, "output_dim", 0)) or None
        self.preprocess = ClipPreprocess(pcfg)
        self._texts = TextEmbeddings(ClipCache(cache_root(cfg.cache_dir), self._weights.path, cfg.model,
                                               self._weights.preprocess),
                                     self._weights)
        self._batch = cfg.batch
        log.info("CLIP %s loaded from %s (%s) on %s, %s", cfg.model, self._weights.path, self._weights.source,
                 self._device, self.precision)

    def _load(self, tower: str) -> torch.nn.Module:
        return load_clip(self._weights, self._cfg.model, tower, self._device, self._precision)

    @property
    def precision(self) -> str:
        return self._precision

    @torch.inference_mode()
    def encode_images_reference(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """The paper's path: open_clip's own PIL transform on each full frame, then the model, no batching tricks
        (the baseline ``merlion bench pipeline`` compares against)."""
        batch = torch.stack([self.preprocess.reference(img) for img in images])
        emb = self._model.encode_image(batch.to(self._device, self._dtype))
        return F.normalize(emb.float(), dim=-1).cpu().numpy().astype(np.float32, copy=False)

    @property
    def input_size(self) -> tuple[int, int]:
        h, w = self.preprocess.size
        return (w, h)

    @torch.inference_mode()
    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for start in range(0, len(images), self._batch):
            batch = torch.stack([self.preprocess(img) for img in images[start:start + self._batch]])
            emb = self._model.encode_image(padded_to(batch.to(self._device, self._dtype), self._batch))[:len(batch)]
            out.append(F.normalize(emb.float(), dim=-1).cpu().numpy())
        if not out:
            return np.zeros((0, self._embed_dim()), dtype=np.float32)
        return np.concatenate(out).astype(np.float32, copy=False)

    def _embed_dim(self) -> int:
        return self._dim or int(self.encode_texts(["x"]).shape[1])

    @property
    def holds_text_tower(self) -> bool:
        """Always False: the text tower only ever runs in the child process that encodes new queries."""
        return any(hasattr(self._model, name) for name in TEXT_TOWER)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """From memory, the disk cache, or a torch child process (``clip_texts``): the text tower is never loaded
        in this process, so a query change adds nothing to its peak."""
        if not texts:
            return np.zeros((0, self._embed_dim()), dtype=np.float32)
        found = self._texts.get(texts)
        return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)

    @property
    def child_peaks_mb(self) -> dict[str, float]:
        """Peak RSS of the torch child processes that encoded queries (transient, so reported apart)."""
        return {"texts": self._texts.child_peak_mb} if self._texts.child_peak_mb else {}

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        return positive_share(image_embeddings, text_embeddings)

    def describe(self) -> dict:
        return {"name": self.name, "model": self._cfg.model, "weights": str(self._weights.path),
                "weights_source": self._weights.source, "precision": self.precision,
                "runtime": "torch",
                "device": str(self._device), "input_size": list(self.input_size)}
