"""Turning a summary.json (and optional per-frame scores) into what the report shows."""

from __future__ import annotations

from pathlib import Path

import cv2

from companion.config import Config, build_config
from companion.evaluation.frame_scores import score_video
from companion.evaluation.report import ReportRun
from companion.vision.encoders.base import Encoder


def _depth(entry: dict) -> float | None:
    for holder in (entry, entry.get("pose") or {}):
        value = holder.get("depth_m") if isinstance(holder, dict) else None
        if isinstance(value, int | float):
            return float(value)
    return None


def run_from_summary(name: str, summary: dict, base: Path, metrics: dict[str, object]) -> ReportRun:
    """A report run from a summary.json's content; pictures are read from the entries' ``file`` (relative to
    the summary's folder), depth from ``depth_m`` or ``pose.depth_m`` when the frames were tagged."""
    run = ReportRun(name=name, metrics=metrics)
    for entry in summary.get("frames", []):
        t = float(entry.get("time_s", 0.0))
        run.frame_times.append(t)
        index = entry.get("index", entry.get("frame_index", "?"))
        run.frame_labels.append(f"#{index} t={t:.1f}s s={float(entry.get('score', 0)):.2f}")
        run.frame_depths.append(_depth(entry))
        file = entry.get("file")
        if file:
            img = cv2.imread(str(base / file))
            if img is not None:
                run.images.append(img)
    if len(run.images) != len(run.frame_times):
        run.images = []
    return run


ENCODER_NAMES = ("clip", "imagenet", "visual")


def summary_config(summary: dict, cfg: Config) -> Config:
    """``cfg`` with the encoder family and the queries a summary.json says it was made with, so re-scoring a
    video reproduces that run's scores (a CLIP run keeps the configured weights and architecture)."""
    data = cfg.model_dump()
    family = str(summary.get("encoder", "")).split(":", 1)[0]
    if family in ENCODER_NAMES:
        data["encoder"]["name"] = family
    params = summary.get("params") or {}
    if params.get("query"):
        data["queries"]["positive"] = params["query"]
    if isinstance(params.get("negatives"), list):
        data["queries"]["negatives"] = [n for n in params["negatives"] if isinstance(n, str)]
    if isinstance(params.get("tau_ss"), int | float):
        data["queries"]["tau_ss"] = params["tau_ss"]
    return build_config(data, origin="summary.json")


def attach_scores(run: ReportRun, video: str | Path, cfg: Config, encoder: Encoder) -> None:
    """Scores every frame of ``video`` for the run's score-over-time plot."""
    vs = score_video(video, encoder, cfg.queries, cfg.encoder.batch)
    run.score_times, run.scores, run.tau = vs.times, [float(s) for s in vs.scores], cfg.queries.tau_ss
