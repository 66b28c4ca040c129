"""How ``merlion archive`` scales with workers: videos per minute with 1, 2, ... local Ray workers, same videos.

Each worker count gets a fresh local Ray (``num_cpus`` = the count, one CPU and one torch thread per task) and a
fresh output folder, over the same clips cut from the given video, so the runs differ only in the worker count.
The wall time is the whole ``run_archive`` call (Ray start-up and one encoder load per worker included: what a
user waits for). Because the machine may be shared, every run also reports the CPU seconds its tasks used and how
busy the whole machine was (all cores, from /proc/stat via psutil), so a poor ratio can be told from a busy box.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import psutil

from companion.archive.campaign import ArchiveOptions, run_archive
from companion.config import Config
from companion.errors import MerlionError


@dataclass
class WorkerRun:
    workers: int
    videos: int
    frames: int
    wall_s: float
    """The whole run_archive call: Ray start-up, planning and the tasks."""
    span_s: float
    """First task start to last task end (the tasks' own clocks): the work Ray spread over the workers."""
    task_cpu_s: float
    machine_busy: float
    """Share of all cores busy during the run (ours and everyone else's), 0..1."""
    encoder_loads: int

    @property
    def videos_per_min(self) -> float:
        return 60.0 * self.videos / self.wall_s

    @property
    def videos_per_min_span(self) -> float:
        return 60.0 * self.videos / self.span_s

    @property
    def our_cores(self) -> float:
        """Cores' worth of CPU our tasks got during their span: what the workers could actually use."""
        return self.task_cpu_s / self.span_s if self.span_s > 0 else 0.0

    @property
    def others_cores(self) -> float:
        """Cores' worth of CPU used by everything but our tasks during the run (other users, and Ray's own
        daemons and the driver)."""
        return max(0.0, self.machine_busy * (os.cpu_count() or 1) - self.task_cpu_s / self.wall_s)


@dataclass
class ArchiveBench:
    runs: list[WorkerRun] = field(default_factory=list)
    encoder: str = ""

    def scaling(self, span: bool = False) -> float | None:
        if len(self.runs) < 2:
            return None
        if span:
            return self.runs[-1].videos_per_min_span / self.runs[0].videos_per_min_span
        return self.runs[-1].videos_per_min / self.runs[0].videos_per_min

    def table(self) -> str:
        lines = [f"merlion archive on local Ray, encoder {self.encoder}, {os.cpu_count()} cores here",
                 "workers  videos  frames  wall s  videos/min  task span s  videos/min (span)  task CPU s"
                 "  tasks' cores  machine busy  others' cores  encoder loads"]
        for r in self.runs:
            lines.append(f"{r.workers:7d}  {r.videos:6d}  {r.frames:6d}  {r.wall_s:6.1f}  {r.videos_per_min:10.2f}"
                         f"  {r.span_s:11.1f}  {r.videos_per_min_span:17.2f}  {r.task_cpu_s:10.1f}"
                         f"  {r.our_cores:12.2f}  {100 * r.machine_busy:11.0f}%  {r.others_cores:13.2f}  {r.encoder_loads:13d}")
        s, s_span = self.scaling(), self.scaling(span=True)
        if s is not None and s_span is not None:
            one, last = self.runs[0], self.runs[-1]
            ratio = last.workers / one.workers
            eff = s_span / ratio
            lines.append(f"scaling {one.workers} -> {last.workers} workers: {s:.2f}x whole run, {s_span:.2f}x task "
                         f"span (efficiency {eff:.0%})")
            lines.append(f"estimate: N workers ~ N x {one.videos_per_min_span / one.workers * eff:.2f} videos/min "
                         f"of clips like these (one worker's task rate x the measured efficiency), plus a fixed "
                         f"~{one.wall_s - one.span_s:.0f} s of Ray start-up per run, while videos >= N and the "
                         f"output storage keeps up")
            per_video = one.task_cpu_s / one.videos
            lines.append(f"CPU-bound estimate (a dedicated core per worker): {per_video:.2f} CPU s per video here "
                         f"(encoder load included), so N workers ~ N x {60.0 / per_video:.1f} videos/min; the "
                         f"measured ratio falls short of it by as much as the cores were busy with other work")
        return "\n".join(lines)

    def as_json(self) -> dict:
        return {"encoder": self.encoder, "scaling": self.scaling(),
                "scaling_span": self.scaling(span=True),
                "runs": [{**r.__dict__, "videos_per_min": r.videos_per_min,
                          "videos_per_min_span": r.videos_per_min_span, "our_cores": r.our_cores,
                          "others_cores": r.others_cores}
                         for r in self.runs]}


def make_clips(video: Path, out_dir: Path, count: int, seconds: float) -> list[Path]:
    """``count`` clips of ``seconds`` from consecutive parts of ``video`` (restarting it when it ends)."""
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise MerlionError(f"{video}: cannot open this video")
    fps = cap.get(cv2.CAP_PROP_FPS) or 10.0
    clips = []
    try:
        for i in range(count):
            path = out_dir / f"clip{i + 1:03d}.mp4"
            writer = None
            for _ in range(max(1, int(round(seconds * fps)))):
                ok, frame = cap.read()
                if not ok:
                    cap.release()
                    cap = cv2.VideoCapture(str(video))
                    ok, frame = cap.read()
                    if not ok:
                        raise MerlionError(f"{video}: no frames could be decoded")
                if writer is None:
                    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                             (frame.shape[1], frame.shape[0]))
                writer.write(frame)
            writer.release()
            clips.append(path)
    finally:
        cap.release()
    return clips


def _busy_fraction(before, after) -> float:
    total = sum(after) - sum(before)
    idle = (after.idle + getattr(after, "iowait", 0.0)) - (before.idle + getattr(before, "iowait", 0.0))
    return 0.0 if total <= 0 else max(0.0, min(1.0, 1.0 - idle / total))


def bench_archive(cfg: Config, video: Path, *, videos: int, seconds: float,
                  workers: list[int]) -> ArchiveBench:
    result = ArchiveBench(encoder=cfg.encoder.name)
    tmp = Path(tempfile.mkdtemp(prefix="merlion-bench-archive-"))
    try:
        (tmp / "clips").mkdir()
        make_clips(video, tmp / "clips", videos, seconds)
        for n in workers:
            out = tmp / f"out-{n}"
            cpu0 = psutil.cpu_times()
            t0 = time.monotonic()
            run = run_archive(cfg, ArchiveOptions([str(tmp / "clips")], out, workers=n, progress=False,
                                                  report=False))
            wall = time.monotonic() - t0
            busy = _busy_fraction(cpu0, psutil.cpu_times())
            if run.failed:
                raise MerlionError(f"bench archive: {len(run.failed)} clips failed: {next(iter(run.failed.values()))}")
            infos = list(run.done.values())
            span = max(i["ended_at"] for i in infos) - min(i["started_at"] for i in infos)
            result.runs.append(WorkerRun(n, len(infos), sum(i["frames_seen"] for i in infos), wall, span,
                                         sum(i["cpu_s"] for i in infos), busy,
                                         sum(bool(i["encoder_loaded"]) for i in infos)))
            shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return result
