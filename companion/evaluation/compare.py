"""MERLION against the ROST-style visual baseline on one labelled video, in one call.

Both runs go through the very same ``companion.vision.summarize.summarize`` (same source, subsampling, sampler, K);
only the encoder differs: the configured one (MERLION) or ``visual`` (no semantic filter). When the frame gate is
on (``gate:``), MERLION also runs with it off on the same video ("MERLION ungated"), and ``gate`` in the result
says what skipping frames cost: each gated summary's SRUM with the ungated one as the reference and the reverse,
and the difference of their SRUM against the oracle, precision and coverage. Each summary is then
scored against the video's per-frame labels (labels_eval: precision, coverage, SRUM vs the oracle, with one
shared oracle of size ``sampler.k``). MERLION's per-frame scores (a second, full-rate pass) give its AUROC and
the score-over-time plot of the report.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2

from companion.config import Config, build_config
from companion.errors import MerlionError, UsageError
from companion.evaluation.auroc import auroc
from companion.evaluation.datasets import LabelTable, load_labels, read_summary_json
from companion.evaluation.frame_scores import score_video
from companion.evaluation.labels_eval import default_query, evaluate_labels, is_positive
from companion.evaluation.report import write_report
from companion.evaluation.runs import run_from_summary
from companion.evaluation.srum import SrumParams
from companion.evaluation.srum import score as srum_score
from companion.vision.encoders.base import Encoder
from companion.vision.summarize import summarize

MERLION = "MERLION"
UNGATED = "MERLION ungated"
BASELINE = "visual baseline"
FOLDERS = {MERLION: "merlion", UNGATED: "merlion-ungated", BASELINE: "visual"}


def _with(cfg: Config, **sections: dict) -> Config:
    data = cfg.model_dump()
    for name, values in sections.items():
        data[name] = {**data[name], **values}
    return build_config(data, origin="eval compare")


def _video_fps(video: Path) -> float:
    cap = cv2.VideoCapture(str(video))
    try:
        return float(cap.get(cv2.CAP_PROP_FPS) or 0.0) or 30.0
    finally:
        cap.release()


def _metrics(table: LabelTable, frames: list[int], query: str | None, k: int) -> dict:
    if not frames:
        return {"frames": [], "precision": None, "coverage": 0.0, "label_coverage": 0.0, "srum_oracle": 0.0}
    scores = evaluate_labels(table, frames, query, k, SrumParams(fps=table.fps or 30.0)).as_dict()
    scores.pop("query")
    return scores


def compare(
    video: str | Path,
    labels: str | Path,
    cfg: Config,
    encoder_factory: Callable[[Config], Encoder],
    *,
    query: str | None = None,
    out_dir: str | Path | None = None,
    report_dir: str | Path | None = None,
    scores: bool = True,
) -> dict:
    """Summarize ``video`` with MERLION and with the baseline; score both against ``labels``."""
    video = Path(video)
    if not video.is_file():
        raise UsageError(f"{video}: no such video file")
    table = load_labels(labels)
    if table.fps is None:
        table.fps = _video_fps(video)
    query = query or default_query(table)
    base = _with(cfg, source={"uri": str(video)})
    plans = [(MERLION, base)]
    if cfg.gate.mode != "none":
        plans.append((UNGATED, _with(base, gate={"mode": "none"})))
    plans.append((BASELINE, _with(base, encoder={"name": "visual"})))
    result: dict = {"video": str(video), "labels": str(labels), "query": query, "k": cfg.sampler.k,
                    "fps": cfg.source.fps, "runs": {}}
    report_runs = []
    with tempfile.TemporaryDirectory(prefix="merlion-compare-") as tmp:
        root = Path(out_dir) if out_dir else Path(tmp)
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise MerlionError(f"--out {root}: cannot create the folder ({err.strerror or err})") from None
        for name, run_cfg in plans:
            encoder = encoder_factory(run_cfg)
            where = root / FOLDERS[name]
            summarize(run_cfg, where, force=True, encoder=encoder)  # progress bar on a terminal
            frames, document = read_summary_json(where)
            stats = document.get("params", {}).get("stats", {})
            metrics = {"encoder": encoder.name, "frames_encoded": stats.get("frames_encoded"),
                       "frames_seen": stats.get("frames_seen"), **_metrics(table, frames, query, cfg.sampler.k)}
            report = run_from_summary(name, document, where, {})
            if scores and name == MERLION:
                vs = score_video(video, encoder, run_cfg.queries, run_cfg.encoder.batch)
                positive = [is_positive(table, i + 1, query) for i in vs.indices if i + 1 in table.labels]
                if len(positive) == len(vs.indices) and 0 < sum(positive) < len(positive):
                    metrics["auroc"] = auroc(vs.scores, positive)
                report.score_times, report.scores = vs.times, [float(s) for s in vs.scores]
                report.tau = run_cfg.queries.tau_ss
            if out_dir:
                metrics["summary_dir"] = str(where)
            report.metrics = metrics
            result["runs"][name] = metrics
            report_runs.append(report)
    if UNGATED in result["runs"]:
        result["gate"] = gate_effect(table, result["runs"][MERLION], result["runs"][UNGATED], query, cfg)
    if report_dir:
        write_report(report_dir, report_runs, title=f"MERLION vs visual baseline: {video.name}")
    return result


def gate_effect(table: LabelTable, gated: dict, ungated: dict, query: str | None, cfg: Config) -> dict:
    """What the gate cost on this video: the two summaries' SRUM against each other and their metric deltas."""
    labels = table.labels
    if query:  # as labels_eval does: only the query label earns credit
        labels = {f: names & {query} for f, names in labels.items()}
    params = SrumParams(fps=table.fps or 30.0)
    a, b = gated["frames"], ungated["frames"]
    both = bool(a) and bool(b)

    def delta(key: str) -> float | None:
        x, y = gated.get(key), ungated.get(key)
        return None if x is None or y is None else round(x - y, 6)

    return {"gate": cfg.gate.model_dump(),
            "srum_gated_vs_ungated": srum_score(a, b, labels, params) if both else None,
            "srum_ungated_vs_gated": srum_score(b, a, labels, params) if both else None,
            "srum_oracle_delta": delta("srum_oracle"), "precision_delta": delta("precision"),
            "coverage_delta": delta("coverage"),
            "encoded_share": (gated["frames_encoded"] / gated["frames_seen"]
                              if gated.get("frames_encoded") is not None and gated.get("frames_seen") else None)}


def _num(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_compare(result: dict) -> str:
    """One line per summary: precision, coverage, SRUM vs the oracle, AUROC when measured."""
    lines = [f"{result['video']}: query {result['query'] or 'any label'}, K {result['k']}, {result['fps']:g} fps"]
    for name, m in result["runs"].items():
        prec = "-" if m["precision"] is None else f"{m['precision']:.3f}"
        extra = f"  AUROC {m['auroc']:.3f}" if "auroc" in m else ""
        lines.append(f"{name:<16} ({m['encoder']}): precision {prec}  coverage {m['coverage']:.3f}  "
                     f"SRUM vs oracle {m['srum_oracle']:.4f}  frames {m['frames']}{extra}")
    g = result.get("gate")
    if g:
        lines.append(f"gate (difference > {g['gate']['threshold']:g}, max gap {g['gate']['max_gap_s']:g} s): "
                     f"{_num(g['encoded_share'], '.2f')} of frames encoded; SRUM gated vs ungated "
                     f"{_num(g['srum_gated_vs_ungated'], '.4f')}, ungated vs gated "
                     f"{_num(g['srum_ungated_vs_gated'], '.4f')}; change vs oracle "
                     f"{_num(g['srum_oracle_delta'], '+.4f')}, precision {_num(g['precision_delta'], '+.3f')}, "
                     f"coverage {_num(g['coverage_delta'], '+.3f')}")
    return "\n".join(lines)
