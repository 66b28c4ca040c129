"""``merlion bench gate``: does the frame gate keep the summary's spread? Gated against ungated, video by video.

Each case runs the very same pipeline twice over the same frames, once with the configured gate and once with
``gate.mode: none``, and compares the two summaries:

- ``srum``: SRUM (the paper's metric, ``companion.evaluation.srum``) of each summary against the case's oracle,
  a K-frame summary dealt round-robin over the case's segments (``labels_eval.oracle_summary``); the gate's promise
  is a gated SRUM within 0.02 of the ungated one;
- ``segments``: how many of the case's segments the summary has a frame in (the gate must cover the same ones);
- ``precision``: the share of summary frames with a fish, where the case has fish labels;
- ``encoder_calls`` and ``video_fps``: frames encoded, and source frames handled per second end to end.

Segments: the survey video's own five (its label file), DeepFish's habitats (its labels.csv), and for a clip
without labels five equal slices of its length; a looped clip's frames are placed by their position in the clip,
so two rounds of the loop are the same segment. The semantic gate is off by default (``queries.tau_ss`` 0: every
encoded frame reaches the sampler), the case where the frame gate alone decides what the sampler sees.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from companion.config import Config, build_config
from companion.evaluation.datasets import LabelTable
from companion.evaluation.labels_eval import oracle_summary
from companion.evaluation.srum import SrumParams
from companion.evaluation.srum import score as srum_score
from companion.sources.factory import open_source
from companion.sources.folder import list_images
from companion.sources.frame_feed import FrameFeed
from companion.vision.encoders.base import Encoder
from companion.vision.pipeline import Pipeline

SLICES = 5
"""Segments of a clip without labels: equal slices of its length."""


@dataclass
class GateCase:
    """One video (or image folder) at one rate; ``frames`` bounds a looped or long source."""

    name: str
    uri: str
    fps: float
    frames: int | None = None
    loop: bool = False
    segment_of: dict[int, str] = field(default_factory=dict)
    """0-based source frame index -> segment (empty: slices of the clip)."""
    fish: dict[int, bool] = field(default_factory=dict)
    clip_frames: int = 0
    """Source frames in one pass of the clip (for slices and loops)."""


@dataclass
class RunResult:
    frames: list[int]
    encoder_calls: int
    seen: int
    seconds: float

    @property
    def video_fps(self) -> float:
        return self.seen / self.seconds if self.seconds else 0.0


def _survey_labels(csv_path: Path) -> tuple[dict[int, str], dict[int, bool]]:
    with csv_path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return ({int(r["frame_index"]): f"segment {r['segment']}" for r in rows},
            {int(r["frame_index"]): r["fish_present"] == "1" for r in rows})


def _deepfish_labels(folder: Path) -> tuple[dict[int, str], dict[int, bool]]:
    with (folder / "labels.csv").open(newline="") as fh:
        rows = {Path(r["file"]).name: r for r in csv.DictReader(fh)}
    files = list_images(folder / "images")
    return ({i: f"habitat {rows[p.name]['habitat_id']}" for i, p in enumerate(files) if p.name in rows},
            {i: rows[p.name]["fish_present"] == "1" for i, p in enumerate(files) if p.name in rows})


def _frame_count(uri: str) -> int:
    cap = cv2.VideoCapture(uri)
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    finally:
        cap.release()


def default_cases(data: Path) -> list[GateCase]:
    """Every video of the shared data that is there: survey at 10 and 5 fps, aquarium, the ROV clips, DeepFish
    as a clip (its first 120 frames: two habitats), and a 1 s ROV clip looped six times."""
    cases: list[GateCase] = []
    survey = data / "survey" / "survey_480x270.mp4"
    if survey.is_file():
        seg, fish = _survey_labels(data / "survey" / "survey_480x270_labels.csv")
        cases += [GateCase(f"survey {fps:g} fps", str(survey), fps, segment_of=seg, fish=fish) for fps in (10.0, 5.0)]
    aquarium = data / "aquarium_fish" / "fish.mp4"
    if aquarium.is_file():
        cases.append(GateCase("aquarium 5 fps", str(aquarium), 5.0, clip_frames=_frame_count(str(aquarium))))
    rov = sorted((data / "rov_clips").glob("*.mp4")) if (data / "rov_clips").is_dir() else []
    for i, clip in enumerate(rov):
        cases.append(GateCase(f"ROV clip {i + 1} 30 fps", str(clip), 30.0, clip_frames=_frame_count(str(clip))))
    deepfish = data / "deepfish"
    if (deepfish / "labels.csv").is_file():
        seg, fish = _deepfish_labels(deepfish)
        cases.append(GateCase("DeepFish as a clip", str(deepfish / "images"), 5.0, frames=120, segment_of=seg,
                              fish=fish))
    if rov:
        cases.append(GateCase("ROV clip 1 looped x6", str(rov[0]), 10.0, frames=60, loop=True,
                              clip_frames=_frame_count(str(rov[0]))))
    return cases


def _config(cfg: Config, case: GateCase, gate_mode: str | None) -> Config:
    data = cfg.model_dump()
    data["source"] = {**data["source"], "uri": case.uri, "fps": case.fps, "loop": case.loop, "realtime": False}
    if gate_mode is not None:
        data["gate"] = {**data["gate"], "mode": gate_mode}
    return build_config(data, origin="bench gate")


def run_case(cfg: Config, case: GateCase, encoder: Encoder) -> RunResult:
    """The pipeline over the case's frames as ``merlion summarize`` drives it (the gate in the decode thread)."""
    pipeline = Pipeline.from_config(cfg, encoder)
    gate = pipeline.gate if pipeline.gate.on else None
    seen = 0
    start = time.perf_counter()
    with FrameFeed(open_source(cfg.source), pipeline.prepare, gate=gate, limit=case.frames) as feed:
        for batch in feed.batches(cfg.encoder.batch):
            pipeline.process([f for f, _ in batch], [s for _, s in batch], gated=feed.gated)
            seen += len(batch)
    seconds = time.perf_counter() - start
    return RunResult(sorted(f.frame_index for f in pipeline.summary), pipeline.counts["encoded"], seen, seconds)


def _segment(case: GateCase, index: int) -> str:
    if case.segment_of:
        return case.segment_of.get(index, "?")
    position = index % case.clip_frames if case.clip_frames else index
    return f"slice {min(SLICES - 1, SLICES * position // max(1, case.clip_frames))}"


def _table(case: GateCase, seen_indices: list[int], fps: float) -> LabelTable:
    """Every handled frame labelled with its segment (1-based frame numbers, as the SRUM code wants them)."""
    labels = {i + 1: frozenset({_segment(case, i)}) for i in seen_indices}
    return LabelTable(labels, case.name, fps=fps, segments={i + 1: _segment(case, i) for i in seen_indices})


def _handled(cfg: Config, case: GateCase) -> list[int]:
    source = open_source(cfg.source)
    try:
        indices = []
        for frame in source:
            indices.append(frame.index)
            if case.frames and len(indices) >= case.frames:
                break
        return indices
    finally:
        source.close()


def compare_case(cfg: Config, case: GateCase, encoder: Encoder) -> dict:
    """Gated and ungated runs of one case and their scores."""
    gated_cfg, ungated_cfg = _config(cfg, case, None), _config(cfg, case, "none")
    indices = _handled(ungated_cfg, case)

    def place(i: int) -> int:  # a looped clip: frames are compared by their position in the clip
        return i % case.clip_frames if case.loop and case.clip_frames else i

    table = _table(case, sorted({place(i) for i in indices}), _source_fps(case))
    k = cfg.sampler.k
    oracle = oracle_summary(table, k, None)
    params = SrumParams(fps=_source_fps(case))
    out: dict = {"case": case.name, "frames": len(indices), "k": k, "oracle": [o - 1 for o in oracle]}
    segments = {table.segments[i] for i in table.segments}
    out["segments_total"] = len(segments)
    for name, run_cfg in (("ungated", ungated_cfg), ("gated", gated_cfg)):
        run = run_case(run_cfg, case, encoder)
        picks = [place(f) + 1 for f in run.frames]
        covered = sorted({table.segments.get(p, "?") for p in picks})
        fish = [case.fish.get(f) for f in run.frames]
        out[name] = {
            "summary": run.frames,
            "srum": srum_score(picks, oracle, table.labels, params) if picks else 0.0,
            "segments": covered,
            "precision": (sum(bool(x) for x in fish) / len(fish)) if fish and None not in fish else None,
            "encoder_calls": run.encoder_calls,
            "video_fps": run.video_fps,
        }
    g, u = out["gated"], out["ungated"]
    out["srum_delta"] = g["srum"] - u["srum"]
    out["same_segments"] = g["segments"] == u["segments"]
    return out


def _source_fps(case: GateCase) -> float:
    """SRUM counts time in source frames: the source's own rate (a folder of images: the case's rate)."""
    if Path(case.uri).is_dir():
        return case.fps
    cap = cv2.VideoCapture(case.uri)
    try:
        return float(cap.get(cv2.CAP_PROP_FPS) or 0.0) or 30.0
    finally:
        cap.release()


def format_table(rows: list[dict]) -> str:
    return "\n".join([table_head()] + [table_row(r) for r in rows])


def table_head() -> str:
    return (f"{'case':<24}{'frames':>7}  {'SRUM gated/ungated':>19}  {'delta':>7}  {'segments g/u/all':>17}  "
            f"{'precision g/u':>13}  {'encoder calls g/u':>17}  {'video fps g/u':>14}")


def table_row(r: dict) -> str:
    """One case: gated/ungated side by side; "!" marks segments that differ."""
    g, u = r["gated"], r["ungated"]
    prec = "-" if g["precision"] is None else f"{g['precision']:.2f}/{u['precision']:.2f}"
    seg = f"{len(g['segments'])}/{len(u['segments'])}/{r['segments_total']}" + ("" if r["same_segments"] else " !")
    return (f"{r['case']:<24}{r['frames']:>7}  {g['srum']:>9.3f}/{u['srum']:<9.3f}  {r['srum_delta']:>+7.3f}  "
            f"{seg:>17}  {prec:>13}  {g['encoder_calls']:>8}/{u['encoder_calls']:<8}  "
            f"{g['video_fps']:>6.1f}/{u['video_fps']:<7.1f}")
