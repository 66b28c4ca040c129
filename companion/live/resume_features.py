"""Resumed summary frames get sampler features from the encoder in use, never one of another encoder's.

The store keeps each summary frame's sampler feature so a restart resumes the same summary without encoding
again. A store written under another encoder (the config changed from CLIP to the packaged one, say) holds
features of another space: of another length they stopped every new frame at the sampler ("feature has 1280
dimensions, the summary holds 379", each batch, while the run went on keeping nothing); of the same length (two
CLIP models) they would be compared with the new ones silently, as if they meant the same. So a resumed frame
whose sidecar names another encoder, or whose feature has another length than this encoder's, is encoded again
from its stored image (the enhanced one where enhancement ran, as the sampler saw it), and the store keeps the new
feature and encoder, so the next start finds them in order. One warning line says which frames.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np

from companion.storage.store import ResumeState, Store
from companion.vision import distances as dist
from companion.vision.encoders.base import Encoder
from companion.vision.events import SummaryFrame

log = logging.getLogger(__name__)

BATCH = 8
"""Frames encoded at once (a summary is a few dozen frames at most)."""


def refresh_features(state: ResumeState, encoder: Encoder, prepare: Callable[[np.ndarray], np.ndarray],
                     store: Store) -> ResumeState:
    """``state`` with every frame's feature from ``encoder``; frames made by another are encoded again."""
    name = encoder.name
    frames = state.frames
    if not frames:
        return state
    made_by = state.encoders
    mine = [f.feature.size for f in frames if made_by.get(f.image_index) == name]
    # this encoder's feature length: from its own frames, else from one frame encoded now
    length = Counter(mine).most_common(1)[0][0] if mine else _features(encoder, prepare, frames[:1])[0].size
    stale = [f for f in frames if made_by.get(f.image_index) not in ("", name) or f.feature.size != length]
    if not stale:
        return state
    why = sorted({f"made by {made_by[f.image_index]}" if made_by.get(f.image_index) not in ("", name)
                  else f"{f.feature.size} values, not {length}" for f in stale})
    for start in range(0, len(stale), BATCH):
        batch = stale[start:start + BATCH]
        for frame, feature in zip(batch, _features(encoder, prepare, batch), strict=True):
            store.replace_feature(frame.image_index, feature, name)
    log.warning("resumed frame(s) %s: stored features not %s's (%s); encoded again from the stored images",
                ", ".join(str(f.image_index) for f in stale), name, "; ".join(why))
    return store.resume_state()


def _features(encoder: Encoder, prepare: Callable[[np.ndarray], np.ndarray],
              frames: Sequence[SummaryFrame]) -> np.ndarray:
    """The sampler features the pipeline makes of these frames' images (float32, as the store keeps them)."""
    embeddings = encoder.encode_images([prepare(f.image) for f in frames])
    return dist.prepare_features(encoder.sampler_features(embeddings)).astype(np.float32)
