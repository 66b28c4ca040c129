"""The driver: find the dives, match their logs, skip the finished ones, run the rest as Ray tasks, report.

Ray does the scheduling (one task per dive, ``num_cpus``/``num_gpus`` per task); the driver only submits, waits
for whichever task finishes next (``ray.wait``), records it in the manifest and moves the progress bars. A local
Ray is started in-process unless ``address`` names a running cluster; the local one has a small object store and
no dashboard, since tasks return only a few numbers (the summaries go straight to the output folder, which must
be shared storage when workers run on other machines).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from companion.archive.dives import find_sources, make_dives
from companion.archive.log_match import LogMatch, find_logs, match_logs, read_mapping
from companion.archive.manifest import Manifest, dive_key
from companion.archive.report import write_campaign_report
from companion.archive.worker import DiveJob, summarize_dive
from companion.config import Config
from companion.errors import MerlionError

log = logging.getLogger(__name__)

LOCAL_OBJECT_STORE_BYTES = 100 * 1024 * 1024
PROGRESS_POLL_S = 0.5


@dataclass
class ArchiveOptions:
    sources: Sequence[str]
    out_dir: Path
    tlogs: Sequence[str] = ()
    mapping: str | None = None
    address: str | None = None
    workers: int | None = None
    """Local Ray only: CPUs to give it (default: the machine's)."""
    cpus_per_task: float = 1.0
    gpus_per_task: float = 0.0
    progress: bool | None = None
    report: bool = True


@dataclass
class ArchiveRun:
    done: dict[str, dict] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    report: Path | None = None


def plan(cfg: Config, opts: ArchiveOptions) -> list[tuple[LogMatch, str]]:
    """Each dive with its log and key, in source order."""
    dives = make_dives(find_sources(opts.sources))
    logs = find_logs(opts.tlogs)
    mapping = read_mapping(opts.mapping) if opts.mapping else None
    return [(m, dive_key(m.dive.source, m.tlog, m.dive.start_time, cfg)) for m in match_logs(dives, logs, mapping)]


def _job(cfg: Config, match: LogMatch, out_dir: Path, progress=None) -> DiveJob:
    dive_cfg = cfg.model_copy(update={"source": cfg.source.model_copy(update={"uri": str(match.dive.source)})})
    return DiveJob(match.dive.name, dive_cfg, str(out_dir / match.dive.name), match.dive.start_time,
                   match.dive.duration_s, str(match.tlog) if match.tlog else None, progress)


class FrameCounter:
    """Frames scored so far over all workers (a Ray actor, so the frame bar moves while videos are running)."""

    def __init__(self) -> None:
        self.frames = 0

    def add(self, n: int) -> None:
        self.frames += n

    def total(self) -> int:
        return self.frames


def _start_ray(opts: ArchiveOptions):
    try:
        import ray  # 1.0 s (measured): only with --workers on ray
    except ImportError:
        raise MerlionError('merlion archive needs Ray: pip install "merlion-companion[archive]"') from None
    if opts.address:
        ray.init(address=opts.address, log_to_driver=False, logging_level=logging.WARNING)
    else:
        ray.init(num_cpus=opts.workers or os.cpu_count() or 1, include_dashboard=False,
                 object_store_memory=LOCAL_OBJECT_STORE_BYTES, log_to_driver=False, logging_level=logging.WARNING)
    _check_resources(ray, opts)
    return ray


def _check_resources(ray, opts: ArchiveOptions) -> None:
    """A task that asks more than any node has would wait forever: refuse it now, naming the option."""
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    wanted = {"CPU": ("--cpus-per-task", opts.cpus_per_task), "GPU": ("--gpus-per-task", opts.gpus_per_task)}
    for resource, (option, amount) in wanted.items():
        if amount > 0 and not any(n.get(resource, 0) >= amount for n in nodes):
            ray.shutdown()
            most = max((n.get(resource, 0) for n in nodes), default=0)
            raise MerlionError(f"{option} {amount:g}: no node of this Ray cluster has that many "
                               f"({resource} per node at most {most:g})")


def _bars(total_dives: int, total_frames: int, enabled: bool | None):
    show = sys.stderr.isatty() if enabled is None else enabled
    videos = tqdm(total=total_dives, unit="video", desc="archive", disable=not show, file=sys.stderr, position=0)
    frames = tqdm(total=total_frames or None, unit="frame", desc="frames", disable=not show, file=sys.stderr,
                  position=1)
    return videos, frames


def _error_line(err: BaseException) -> str:
    """The one line a failed task's error comes down to (Ray wraps the worker's exception)."""
    cause = getattr(err, "cause", None) or err
    text = str(cause).strip().splitlines()
    return text[-1] if text else type(cause).__name__


def run_archive(cfg: Config, opts: ArchiveOptions) -> ArchiveRun:
    """Summarize every dive not already finished with the same key; failures are recorded, never fatal."""
    out_dir = opts.out_dir.resolve()
    if out_dir.exists() and not out_dir.is_dir():
        raise MerlionError(f"{out_dir}: exists and is not a directory")
    if not out_dir.parent.is_dir():
        raise MerlionError(f"{out_dir}: parent directory {out_dir.parent} does not exist")
    out_dir.mkdir(exist_ok=True)
    manifest = Manifest.load(out_dir)
    planned = plan(cfg, opts)
    result = ArchiveRun()
    todo = []
    for match, key in planned:
        if manifest.is_done(match.dive.name, key):
            result.skipped.append(match.dive.name)
        else:
            todo.append((match, key))
    if todo:
        _run_tasks(cfg, opts, out_dir, manifest, todo, result)
    if opts.report:
        names = [m.dive.name for m, _ in planned if m.dive.name in manifest.finished]
        result.report = write_campaign_report(out_dir, names)
    return result


def _interrupt_on_sigterm() -> Callable[[], None]:
    """SIGTERM (systemd, a batch system, ``kill``) unwinds like Ctrl-C, so the local Ray is shut down and leaves
    no processes behind; returns what restores the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    return lambda: signal.signal(signal.SIGTERM, previous)


def _run_tasks(cfg: Config, opts: ArchiveOptions, out_dir: Path, manifest: Manifest,
               todo: list[tuple[LogMatch, str]], result: ArchiveRun) -> None:
    ray = _start_ray(opts)
    restore = _interrupt_on_sigterm()  # after ray.init, which installs a handler of its own
    try:
        # max_calls=0: a worker is reused for any number of dives, GPU ones included (Ray's default for GPU tasks
        # is a fresh process per task, which would load the encoder once per video)
        task = ray.remote(num_cpus=opts.cpus_per_task, num_gpus=opts.gpus_per_task, max_retries=0,
                          max_calls=0)(summarize_dive)
        counter = ray.remote(FrameCounter).options(num_cpus=0).remote()
        pending = {}
        for match, key in todo:
            ref = task.remote(_job(cfg, match, out_dir, counter))
            pending[ref] = (match, key)
        expected = sum(_expected_frames(m, cfg.source.fps) for m, _ in todo)
        videos, frames = _bars(len(todo), expected, opts.progress)
        with videos, frames:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=PROGRESS_POLL_S)
                frames.update(ray.get(counter.total.remote()) - frames.n)
                if not ready:
                    continue
                match, key = pending.pop(ready[0])
                name = match.dive.name
                try:
                    info = ray.get(ready[0])
                except Exception as err:  # the task's own error, or its worker died: this dive only
                    line = _error_line(err)
                    log.error("%s: failed: %s", match.dive.source, line)
                    result.failed[name] = line
                    manifest.mark_failed(name, key, line)
                else:
                    info = {**info, "source": str(match.dive.source),
                            "tlog": str(match.tlog) if match.tlog else None}
                    manifest.mark_finished(name, key, info)
                    result.done[name] = info
                videos.update(1)
                videos.set_postfix(failed=len(result.failed))
    finally:
        ray.shutdown()
        restore()


def _expected_frames(match: LogMatch, fps: float) -> int:
    d = match.dive
    if d.source_fps > 0 and d.frame_count:
        return math.ceil(d.frame_count * min(1.0, fps / d.source_fps))
    return d.frame_count
