"""One dive on one worker: ``merlion summarize``'s own function, then the log's pose at every summary frame.

This module runs inside Ray worker processes (the driver wraps ``summarize_dive`` with ``ray.remote``). Ray reuses
a worker process for many tasks, so the encoder is kept in a per-process cache keyed by its settings: it is loaded
once per worker, not once per video. Beside what ``summarize`` writes, a dive folder gets ``tags.json`` (the pose
of every summary frame and a depth track for the report) and ``scores.csv`` (the score of every frame seen).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.archive.tlog_stream import poses_at
from companion.atomic_write import atomic_write
from companion.config import Config
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.factory import make_encoder
from companion.vision.pipeline import FrameResult
from companion.vision.summarize import summarize

_ENCODERS: dict[str, Encoder] = {}
DEPTH_TRACK_STEP_S = 1.0


@dataclass(frozen=True)
class DiveJob:
    """Everything a worker needs, plain and picklable (paths as strings: the worker may be another machine)."""

    name: str
    cfg: Config
    """The campaign's configuration with ``source.uri`` set to this dive's video or folder."""
    out_dir: str
    """This dive's folder (written by ``summarize`` into place, replaced if a previous run left one)."""
    start_time: float
    duration_s: float
    tlog: str | None
    progress: Any = None
    """A Ray actor handle with ``add(n)`` for the driver's frame bar (None: nobody is watching)."""


def _encoder(cfg: Config) -> tuple[Encoder, bool]:
    """The cached encoder for these settings, and whether this call had to load it."""
    key = cfg.encoder.model_dump_json()
    if key in _ENCODERS:
        return _ENCODERS[key], False
    _ENCODERS[key] = make_encoder(cfg.encoder)
    return _ENCODERS[key], True


def _limit_threads() -> None:
    """Match torch's intra-op threads to the CPUs Ray gave this task, so N workers do not fight over N cores."""
    try:
        import ray  # 1.0 s (measured): only with --workers on ray

        cpus = ray.get_runtime_context().get_assigned_resources().get("CPU")
    except Exception:  # not inside Ray (tests call the function directly)
        return
    torch = sys.modules.get("torch")  # only an encoder that uses torch has imported it; never import it here
    if cpus and torch is not None:
        torch.set_num_threads(max(1, int(math.ceil(cpus))))


def _plain(pose_dict: dict) -> dict:
    """A pose as strict JSON: an infinite age (nothing near) becomes null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in pose_dict.items()}


def _frame_tags(job: DiveJob, frames: Sequence[dict]) -> dict:
    doc: dict = {"tlog": job.tlog, "start_time": job.start_time, "frames": [], "depth_track": []}
    if job.tlog is None:
        doc["frames"] = [{"index": f["index"], "time_s": f["time_s"], "wall_time": job.start_time + f["time_s"],
                          "pose": None} for f in frames]
        return doc
    steps = int(job.duration_s // DEPTH_TRACK_STEP_S) + 1
    grid = [i * DEPTH_TRACK_STEP_S for i in range(steps)]
    rel_times = [f["time_s"] for f in frames] + grid
    poses = poses_at(job.tlog, [job.start_time + t for t in rel_times], job.cfg.telemetry)
    for f, pose in zip(frames, poses[:len(frames)], strict=True):
        doc["frames"].append({"index": f["index"], "time_s": f["time_s"], "wall_time": pose.time,
                              "pose": _plain(pose.to_dict())})
    doc["depth_track"] = [[t, p.depth_m] for t, p in zip(grid, poses[len(frames):], strict=True)
                          if not p.stale and p.depth_m is not None]
    return doc


def summarize_dive(job: DiveJob) -> dict:
    """Summarize and tag one dive; returns counts and timings for the driver (raises MerlionError on bad input)."""
    started, started_at, cpu0 = time.monotonic(), time.time(), time.process_time()
    encoder, loaded = _encoder(job.cfg)
    _limit_threads()
    scores: list[tuple[int, float, float]] = []

    def keep_scores(results: Sequence[FrameResult]) -> None:
        scores.extend((r.frame_index, r.time_s, float(r.score)) for r in results)
        if job.progress is not None:
            job.progress.add.remote(len(results))  # fire and forget: never waits on the driver

    out = Path(job.out_dir)
    run = summarize(job.cfg, out, force=True, encoder=encoder, progress=False, on_results=keep_scores)
    tags = _frame_tags(job, run.document["frames"])
    atomic_write(out / "tags.json", json.dumps(tags, indent=2) + "\n")
    atomic_write(out / "scores.csv", "index,time_s,score\n" + "".join(
        f"{i},{t:.4f},{s:.6f}\n" for i, t, s in scores))
    return {"frames_seen": run.frames_seen, "frames_passed": run.frames_passed, "frames_lost": run.frames_lost,
            "summary_frames": len(run.document["frames"]), "worker_pid": os.getpid(), "encoder_loaded": loaded,
            "wall_s": round(time.monotonic() - started, 3), "cpu_s": round(time.process_time() - cpu0, 3),
            "started_at": started_at, "ended_at": time.time()}
