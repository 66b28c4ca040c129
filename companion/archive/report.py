"""The campaign report: one HTML page over all dives, and an index of every summary frame (CSV and JSON).

Per dive the page shows its contact sheet (written by ``summarize``), its depth profile from the log with the
summary frames marked, and its score over time with the threshold. The pages and PNGs sit in the output folder
and reference the dive folders by relative path, so the whole folder can be copied and opened anywhere. Plots
use matplotlib's Agg backend; a dive without a log gets no depth plot and the page says so.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from datetime import datetime, timezone
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.evaluation.plots import plot_depth, plot_scores
from companion.export.viame_csv import sheet_safe
from companion.export.writer import write_campaign_exports
from vehicle.autopilot.pose import wrap_heading

INDEX_FIELDS = ("dive", "time_s", "wall_time_utc", "depth_m", "heading_deg", "lat", "lon", "topic", "score",
                "file", "query")
"""``topic`` is the topic's name (``queries.name``, "main", with one topic); ``query``, last so that readers by
column position keep working, its positive query."""


def _load(out_dir: Path, name: str) -> tuple[dict, dict, list[tuple[float, float]]]:
    dive = out_dir / name
    summary = json.loads((dive / "summary.json").read_text(encoding="utf-8"))
    tags_path = dive / "tags.json"
    tags = json.loads(tags_path.read_text(encoding="utf-8")) if tags_path.exists() else {"frames": []}
    scores: list[tuple[float, float]] = []
    scores_path = dive / "scores.csv"
    if scores_path.exists():
        for row in csv.DictReader(scores_path.read_text(encoding="utf-8").splitlines()):
            scores.append((float(row["time_s"]), float(row["score"])))
    return summary, tags, scores


def _plot_depth(name: str, tags: dict, path: Path) -> bool:
    track = tags.get("depth_track") or []
    marked = [(f["time_s"], f["pose"]["depth_m"]) for f in tags.get("frames", [])
              if f.get("pose") and f["pose"].get("depth_m") is not None]
    if not track and not marked:
        return False
    plot_depth(path, name, [tuple(p) for p in track], marked, xlabel="time in video (s)", track_label="depth (log)")
    return True


def _plot_scores(name: str, summary: dict, scores: list[tuple[float, float]], path: Path) -> bool:
    if not scores:
        return False
    marked = [(f["time_s"], f["score"]) for f in summary.get("frames", [])]
    plot_scores(path, name, scores, marked, tau=summary["params"].get("tau_ss"), xlabel="time in video (s)")
    return True


def _topics(summary: dict) -> list[dict]:
    """The topics a summary.json followed (one, from its query, when written before topics existed)."""
    params = summary["params"]
    return params.get("topics") or [{"name": "", "query": params["query"], "contact_sheet": "contact_sheet.jpg"}]


def _utc(t: float | None) -> str:
    return "" if t is None else datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


def _heading(value: object) -> object:
    """A heading in [0, 360) (a tags.json written before ``wrap_heading`` may hold 360.0); anything else as is."""
    if isinstance(value, float) and math.isfinite(value):
        return wrap_heading(value)
    return value


def index_rows(out_dir: Path, names: list[str]) -> list[dict]:
    """One row per summary frame of every dive, in dive then time order."""
    rows = []
    for name in names:
        summary, tags, _ = _load(out_dir, name)
        poses = {f["index"]: f for f in tags.get("frames", [])}
        queries = {t["name"]: t["query"] for t in _topics(summary)}
        for f in summary["frames"]:
            tag = poses.get(f["index"], {})
            pose = tag.get("pose") or {}
            rows.append({"dive": name, "time_s": f["time_s"], "wall_time_utc": _utc(tag.get("wall_time")),
                         "depth_m": pose.get("depth_m"), "heading_deg": _heading(pose.get("heading_deg")),
                         "lat": pose.get("lat"), "lon": pose.get("lon"), "topic": f.get("topic", ""),
                         "query": queries.get(f.get("topic", ""), summary["params"]["query"]),
                         "score": f["score"], "file": f"{name}/{f['file']}"})
    return rows


def write_campaign_report(out_dir: Path, names: list[str]) -> Path:
    """index.html, index.csv and index.json in ``out_dir`` over the finished dives ``names``."""
    plots = out_dir / "report"
    plots.mkdir(exist_ok=True)
    rows = index_rows(out_dir, names)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=INDEX_FIELDS, lineterminator="\n")
    writer.writeheader()
    # a query is anyone's text on the link: no cell of it may run as a spreadsheet formula (index.json keeps it)
    writer.writerows({k: sheet_safe(v) if isinstance(v, str) else v for k, v in row.items()} for row in rows)
    atomic_write(out_dir / "index.csv", buf.getvalue())
    atomic_write(out_dir / "index.json", json.dumps(rows, indent=2) + "\n")
    exports = write_campaign_exports(out_dir, names)
    parts = [f"<!doctype html><meta charset='utf-8'><title>MERLION campaign</title>"
             f"<h1>MERLION campaign: {len(names)} dives, {len(rows)} summary frames</h1>"
             f"<p>Index of every summary frame: <a href='index.csv'>index.csv</a>, "
             f"<a href='index.json'>index.json</a></p>"
             f"<p>For science tools: <a href='{exports['fathomnet'].name}'>FathomNet image records</a>, "
             f"<a href='{exports['coco'].name}'>COCO</a>, <a href='{exports['csv'].name}'>VIAME/DIVE CSV</a></p>"]
    for name in names:
        summary, tags, scores = _load(out_dir, name)
        esc = html.escape(name)
        topics = _topics(summary)
        asked = "; ".join(f"{html.escape(t['name'] + ': ') if len(topics) > 1 else ''}"
                          f"&ldquo;{html.escape(t['query'])}&rdquo;" for t in topics)
        parts.append(f"<h2>{esc}</h2><p>{html.escape(summary['source'])} | query {asked} | "
                     f"{len(summary['frames'])} frames | log: {html.escape(str(tags.get('tlog') or 'none matched'))}</p>")
        for t in topics:
            sheet = html.escape(t["contact_sheet"])
            parts.append(f"<img src='{esc}/{sheet}' alt='contact sheet {html.escape(t['name'])}' "
                         f"style='max-width:100%'><br>")
        if _plot_depth(name, tags, plots / f"{name}_depth.png"):
            parts.append(f"<img src='report/{esc}_depth.png' alt='depth profile'>")
        else:
            parts.append("<p>No depth: no log covers this dive.</p>")
        if _plot_scores(name, summary, scores, plots / f"{name}_scores.png"):
            parts.append(f"<img src='report/{esc}_scores.png' alt='score over time'>")
    page = out_dir / "index.html"
    atomic_write(page, "\n".join(parts) + "\n")
    return page
