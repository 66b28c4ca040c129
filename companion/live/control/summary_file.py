"""/store/summary.json over MAVLink FTP: what the summary keeper holds, for audits from the surface."""

from __future__ import annotations

import json
from typing import Any

from companion.live.control.context import ControlContext
from companion.live.control.marks import MarksHandler

KEEPER_PATH = "/store/summary.json"
"""The summary the keeper holds, with its recent history (see SummaryKeeper.document)."""


def keeper_document(ctx: ControlContext, marks: MarksHandler) -> dict[str, Any]:
    """The keeper's summary and history, each frame's topic, and what the encoder did, all read under the
    keeper's lock (so the counts belong to the same moment as the summary).

    ``encoder.images`` counts what the encoder itself was given; ``scored`` the images whose scores were computed
    (each frame once, and with enhance.mode selective each enhanced version once more) and ``marks`` the marked
    frames embedded. ``images == scored + marks`` however many topics are followed: one encoder pass serves them
    all.
    """
    with ctx.keeper.lock:
        doc = ctx.keeper.document()
        doc["topics"] = {t.name: [f.image_index for f in t.summary] for t in ctx.pipeline.topics}
        scored = ctx.pipeline.counts["encoded"] + (ctx.selective.scored if ctx.selective is not None else 0)
        doc["encoder"] = {"images": ctx.encoder.images, "calls": ctx.encoder.calls, "scored": scored,
                          "marks": marks.images}
    return doc


def serve_keeper_document(ctx: ControlContext, marks: MarksHandler) -> None:
    """Put the document on the surface link's FTP tree (computed on each read)."""
    if ctx.surface is not None:
        ctx.surface.tree.put(KEEPER_PATH, lambda: json.dumps(keeper_document(ctx, marks)).encode())
