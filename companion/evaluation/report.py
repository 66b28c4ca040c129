"""An HTML report of one or more summaries: contact sheet, score over time, depth profile, metric table.

Plain files a reviewer can open anywhere: ``index.html`` beside PNGs it references by relative name. Plots use
matplotlib's Agg backend (no display on the vehicle or in CI). Parts without data (no per-frame scores, no
depth tags) are left out and the page says so, rather than drawing an empty plot.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.errors import MerlionError
from companion.evaluation.plots import plot_depth, plot_scores


@dataclass
class ReportRun:
    """One summary to show: its frames (with pictures when available), scores and depth tags."""

    name: str
    metrics: dict[str, object]
    frame_times: list[float] = field(default_factory=list)
    """Time (s) of each summary frame."""
    frame_labels: list[str] = field(default_factory=list)
    """Caption of each summary frame (e.g. "#37 t=3.7s")."""
    images: list[np.ndarray] = field(default_factory=list)
    """BGR pictures of the summary frames (may be empty)."""
    frame_depths: list[float | None] = field(default_factory=list)
    """Depth (m, positive down) of each summary frame when tagged."""
    score_times: list[float] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    """Semantic score of every frame seen (may be empty)."""
    tau: float | None = None
    depth_times: list[float] = field(default_factory=list)
    depths: list[float] = field(default_factory=list)
    """The whole dive's depth profile, when known."""


def contact_sheet(images: Sequence[np.ndarray], captions: Sequence[str], tile_w: int = 240, cols: int = 3) -> np.ndarray:
    """A grid of the summary frames, each captioned, as one BGR image."""
    tiles = []
    for img, cap in zip(images, captions, strict=False):
        h = max(1, round(img.shape[0] * tile_w / img.shape[1]))
        tile = cv2.resize(img, (tile_w, h), interpolation=cv2.INTER_AREA)
        band = np.full((22, tile_w, 3), 255, np.uint8)
        cv2.putText(band, cap[:34], (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.vstack([tile, band]))
    tile_h = max(t.shape[0] for t in tiles)
    tiles = [np.vstack([t, np.full((tile_h - t.shape[0], tile_w, 3), 255, np.uint8)]) for t in tiles]
    while len(tiles) % cols:
        tiles.append(np.full((tile_h, tile_w, 3), 255, np.uint8))
    rows = [np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)]
    return np.vstack(rows)


def _plot_scores(run: ReportRun, path: Path) -> None:
    marked = list(zip(run.frame_times, np.interp(run.frame_times, run.score_times, run.scores), strict=True)) \
        if run.frame_times else []
    plot_scores(path, run.name, list(zip(run.score_times, run.scores, strict=True)), marked, tau=run.tau,
                ylim=(-0.02, 1.02))


def _plot_depth(run: ReportRun, path: Path) -> None:
    tagged = [(t, d) for t, d in zip(run.frame_times, run.frame_depths, strict=False) if d is not None]
    plot_depth(path, run.name, list(zip(run.depth_times, run.depths, strict=True)), tagged)


def _slug(name: str) -> str:
    words = "".join(c if c.isalnum() else " " for c in name).split()
    return "_".join(words).lower() or "run"


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    if isinstance(value, list):
        return ", ".join(str(v) for v in value)
    return str(value)


def write_report(out_dir: str | Path, runs: Sequence[ReportRun], title: str = "MERLION evaluation") -> Path:
    """Writes ``index.html`` and its PNGs into ``out_dir`` (created); returns the HTML path."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise MerlionError(f"{out}: cannot create the report folder ({err.strerror})") from None
    keys: list[str] = []
    for run in runs:
        keys += [k for k in run.metrics if k not in keys]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse}"
             "td,th{border:1px solid #999;padding:3px 8px;text-align:left}img{max-width:100%}</style>",
             f"</head><body><h1>{html.escape(title)}</h1><h2>Metrics</h2><table><tr><th>metric</th>"]
    parts += [f"<th>{html.escape(r.name)}</th>" for r in runs] + ["</tr>"]
    for k in keys:
        cells = "".join(f"<td>{html.escape(_fmt(r.metrics.get(k, '-')))}</td>" for r in runs)
        parts.append(f"<tr><td>{html.escape(k)}</td>{cells}</tr>")
    parts.append("</table>")
    for run in runs:
        slug = _slug(run.name)
        parts.append(f"<h2>{html.escape(run.name)}</h2>")
        if run.images:
            name = f"{slug}_contact_sheet.png"
            caps = run.frame_labels or [f"frame {i}" for i in range(len(run.images))]
            if not cv2.imwrite(str(out / name), contact_sheet(run.images, caps)):
                raise MerlionError(f"{out / name}: cannot write the contact sheet")
            parts.append(f"<h3>Contact sheet</h3><img src='{name}' alt='contact sheet'>")
        else:
            parts.append("<p>No summary pictures were available.</p>")
        if run.scores:
            name = f"{slug}_score.png"
            _plot_scores(run, out / name)
            parts.append(f"<h3>Score over time</h3><img src='{name}' alt='score over time'>")
        else:
            parts.append("<p>No per-frame scores were recorded for this summary.</p>")
        if run.depths or any(d is not None for d in run.frame_depths):
            name = f"{slug}_depth.png"
            _plot_depth(run, out / name)
            parts.append(f"<h3>Depth profile</h3><img src='{name}' alt='depth profile'>")
        else:
            parts.append("<p>No depth tags: the summary was taken without vehicle telemetry.</p>")
    parts.append("</body></html>")
    page = out / "index.html"
    page.write_text("\n".join(parts), encoding="utf-8")
    return page
