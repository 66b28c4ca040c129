"""The paper's encoder: an open_clip model (any architecture, ViT-B-32 by default) with weights found offline.

Scores follow REFERENCE.md exactly: L2-normalised embeddings, softmax of 100 x cosine over [positive, negatives],
the positive's share (the fixed scale 100, not the model's learned logit scale). Preprocessing is read from the
loaded model (size, mean/std, interpolation, resize mode), so it is always the one its weights were trained with;
it runs in torch on uint8 frames (faster than PIL), and a test holds it to open_clip's own transform.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import open_clip
import torch
import torch.nn.functional as F
from PIL import Image

from companion.config import EncoderConfig
from companion.encoders.base import Encoder
from companion.encoders.torch_runtime import configure_threads, dtype_name, pick_device, pick_dtype
from companion.encoders.weights import ResolvedWeights, resolve_clip_weights
from companion.errors import MerlionError

log = logging.getLogger(__name__)

SCALE = 100.0
"""REFERENCE.md: the reference implementation's fixed softmax scale."""


def _as_pair(size: int | Sequence[int]) -> tuple[int, int]:
    """open_clip sizes are an int or (height, width)."""
    if isinstance(size, int):
        return size, size
    return int(size[0]), int(size[1])


class ClipPreprocess:
    """open_clip's eval transform, done in torch on BGR uint8 arrays.

    Matches torchvision's Resize (shortest side, output rounded like PIL to uint8) + CenterCrop + Normalize for
    the "shortest" and "squash" modes; other modes fall back to open_clip's own PIL transform.
    """

    def __init__(self, cfg: dict) -> None:
        self.size = _as_pair(cfg.get("size", 224))
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
        if self.mode == "squash":
            new_h, new_w = th, tw
        elif h <= w:  # torchvision: the short side becomes `size`, the long side is truncated, not rounded
            new_h, new_w = th, int(th * w / h)
        else:
            new_h, new_w = int(tw * h / w), tw
        if (new_h, new_w) != (h, w):
            x = F.interpolate(x, size=(new_h, new_w), mode=self.interpolation, align_corners=False,
                              antialias=True)
            x = x.clamp_(0, 255).round_()  # PIL resizes to uint8: keep the same rounding
        top = int(round((new_h - th) / 2.0))
        left = int(round((new_w - tw) / 2.0))
        x = x[0, :, top:top + th, left:left + tw]
        return (x / 255.0 - self.mean) / self.std


class ClipEncoder(Encoder):
    """Image and text towers of an open_clip model at the configured precision, batched, in inference mode."""

    def __init__(self, cfg: EncoderConfig, *, resolved: ResolvedWeights | None = None) -> None:
        configure_threads()
        self.name = f"clip:{cfg.model}"
        self._cfg = cfg
        self._weights = resolved or resolve_clip_weights(cfg.model, cfg.weights, cfg.pretrained)
        self._device = pick_device(cfg.device)
        self._dtype = pick_dtype(cfg.precision, self._device)
        self._model = self._load()
        pcfg = open_clip.get_model_preprocess_cfg(self._model)
        self.preprocess = ClipPreprocess(pcfg)
        self._tokenizer = open_clip.get_tokenizer(cfg.model)
        self._batch = cfg.batch
        log.info("CLIP %s loaded from %s (%s) on %s, %s", cfg.model, self._weights.path, self._weights.source,
                 self._device, dtype_name(self._dtype))

    def _load(self) -> torch.nn.Module:
        path = self._weights.path
        model_name = f"local-dir:{path}" if path.is_dir() else self._cfg.model
        kwargs: dict = {"device": "cpu", "precision": "fp32"}
        if not path.is_dir():
            kwargs["pretrained"] = str(path)
        if self._weights.preprocess:
            kwargs["force_preprocess_cfg"] = self._weights.preprocess
        try:
            model = open_clip.create_model(model_name, pretrained_text=False, **kwargs)
        except Exception as err:  # torch/open_clip raise many kinds for a bad or mismatched file
            reason = " ".join(str(err).split())[:160]
            raise MerlionError(f"CLIP weights {path} do not load into {self._cfg.model}: {reason}") from None
        return model.eval().to(device=self._device, dtype=self._dtype)

    @property
    def input_size(self) -> tuple[int, int]:
        h, w = self.preprocess.size
        return (w, h)

    @torch.inference_mode()
    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for start in range(0, len(images), self._batch):
            batch = torch.stack([self.preprocess(img) for img in images[start:start + self._batch]])
            emb = self._model.encode_image(batch.to(self._device, self._dtype))
            out.append(F.normalize(emb.float(), dim=-1).cpu().numpy())
        if not out:
            return np.zeros((0, self._embed_dim()), dtype=np.float32)
        return np.concatenate(out).astype(np.float32, copy=False)

    def _embed_dim(self) -> int:
        return int(self.encode_texts(["x"]).shape[1])

    @torch.inference_mode()
    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        tokens = self._tokenizer(list(texts)).to(self._device)
        emb = self._model.encode_text(tokens)
        return F.normalize(emb.float(), dim=-1).cpu().numpy().astype(np.float32, copy=False)

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        logits = SCALE * (image_embeddings.astype(np.float64) @ text_embeddings.astype(np.float64).T)
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        return (p[:, 0] / p.sum(axis=1)).astype(np.float32)

    def sampler_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        return image_embeddings

    def describe(self) -> dict:
        return {"name": self.name, "model": self._cfg.model, "weights": str(self._weights.path),
                "weights_source": self._weights.source, "precision": dtype_name(self._dtype),
                "device": str(self._device), "input_size": list(self.input_size)}
