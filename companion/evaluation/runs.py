"""Turning a summary.json (and optional per-frame scores) into what the report shows."""

from __future__ import annotations

from pathlib import Path

import cv2

from companion.evaluation.report import ReportRun


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
