"""What each configured query resolves to, for ``merlion score --explain`` and ``merlion summarize --explain``.

The packaged encoder reads a query through WordNet (``encoders.query_words``): the operator sees, per query, the
noun each phrase was read as and the ImageNet classes it reached, before trusting a score. CLIP embeds a text as
written, so for it the line says only that.
"""

from __future__ import annotations

import numpy as np

from companion.config import Config, EncoderConfig
from companion.errors import MerlionError
from companion.vision.encoders.imagenet_synsets import CLASSES
from companion.vision.encoders.learned_head import HEADS_DIR, load_head
from companion.vision.encoders.query_cache import resolve_cached
from companion.vision.encoders.query_words import ResolvedQuery
from companion.vision.encoders.weights import clip_weights_available


def scoring_encoder(cfg: EncoderConfig) -> str:
    """The encoder a run will score with: ``auto`` is CLIP when its weights are on disk, else imagenet."""
    if cfg.name != "auto":
        return cfg.name
    ok, _ = clip_weights_available(cfg.model, cfg.weights, cfg.pretrained)
    return "clip" if ok else "imagenet"


def explain_queries(cfg: Config) -> list[str]:
    """Lines saying what each topic's positive and negative queries resolve to under the configured encoder."""
    encoder = scoring_encoder(cfg.encoder)
    topics = cfg.queries.topic_list()
    lines = [f"queries, as the {encoder} encoder reads them:"]
    for topic in topics:
        prefix = f"[{topic.name}] " if len(topics) > 1 else ""
        for role, text in [("positive", topic.positive), *(("negative", n) for n in topic.negatives)]:
            if encoder != "imagenet":
                lines.append(f"{prefix}{role} {text!r}: embedded as written")
                continue
            try:
                resolved = resolve_cached(text, cfg.encoder.cache_dir)
            except MerlionError as err:
                lines.append(f"{prefix}{role} {text!r}: not scored: {err}")
                continue
            lines.append(f"{prefix}{role} {resolved.explain()}")
            if role == "positive" and (head := head_line(resolved)):
                lines.append(head)
    return lines


def head_line(resolved: ResolvedQuery) -> str | None:
    """The line saying a learned head, not the classes, scores a positive query (``learned_head``): "fish" is
    answered by the fish heads, and a place phrase beside it ("near coral") is then not read at all."""
    weights = np.zeros(CLASSES)
    for c, w in resolved.weights.items():
        weights[c] = w
    concepts = sorted({h.concept for h in map(load_head, sorted(HEADS_DIR.glob("*.json"))) if h.matches(weights)})
    if not concepts:
        return None
    places = [t.phrase for t in resolved.terms if t.context]
    unread = f"; where it is ({', '.join(places)}) is not read by them" if places else ""
    return f"  scored by the learned {'/'.join(concepts)} heads (trained on underwater frames), not those classes{unread}"
