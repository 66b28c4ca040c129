"""``merlion archive SOURCES... --out DIR``: summarize a campaign of dives on Ray, tagged from the dive logs."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.commands.overrides import OPTION_NAMES, Overrides, add_summary_options, put_summary_options
from companion.errors import UsageError


def register(add_command) -> None:
    p = add_command("archive", "summarize many videos/image folders on Ray, tagged with depth and pose from .tlog "
                               "logs; resumable; campaign report")
    p.add_argument("sources", nargs="+", metavar="SOURCE", help="video, image folder, or folder of videos")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="campaign folder (one folder per dive)")
    p.add_argument("--tlog", action="append", default=[], metavar="LOG",
                   help="telemetry log (.tlog) or folder of logs, repeatable; matched to dives by file times")
    p.add_argument("--mapping", metavar="CSV", help="explicit video,tlog,offset_s mapping (offset from log start)")
    p.add_argument("--address", metavar="ADDR", help="join a running Ray cluster (default: local Ray in-process)")
    p.add_argument("--workers", type=int, help="local Ray: CPUs to use (default: all of this machine)")
    p.add_argument("--cpus-per-task", type=float, default=1.0, help="CPUs per dive task (default 1)")
    p.add_argument("--gpus-per-task", type=float, default=0.0, help="GPUs per dive task where GPUs exist")
    add_summary_options(p, weights_help="local CLIP checkpoint file (on every worker)")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report and frame index")
    p.set_defaults(func=run)


def overrides_from(args: argparse.Namespace) -> Overrides:
    over: Overrides = {}
    put_summary_options(over, args)
    return over


def run(args: argparse.Namespace) -> int:
    from companion.archive.campaign import ArchiveOptions, run_archive

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    if args.cpus_per_task <= 0:
        raise UsageError(f"--cpus-per-task must be more than 0, got {args.cpus_per_task}")
    if args.gpus_per_task < 0:
        raise UsageError(f"--gpus-per-task must be 0 or more, got {args.gpus_per_task}")
    if args.address and args.workers:
        raise UsageError("--workers applies to the local Ray only; the cluster at --address has its own CPUs")
    from companion.config import load_config  # pydantic: 0.15-0.25 s measured, not for every merlion call

    cfg = load_config(args.config, overrides=overrides_from(args), options=OPTION_NAMES)
    opts = ArchiveOptions(args.sources, Path(args.out), tlogs=args.tlog, mapping=args.mapping,
                          address=args.address, workers=args.workers, cpus_per_task=args.cpus_per_task,
                          gpus_per_task=args.gpus_per_task, report=not args.no_report)
    result = run_archive(cfg, opts)
    for name, error in result.failed.items():
        print(f"{name}: FAILED: {error}")
    report = f"; report {result.report}" if result.report else ""
    print(f"{args.out}: {len(result.done)} dives summarized, {len(result.skipped)} already done (skipped), "
          f"{len(result.failed)} failed{report}")
    return 1 if result.failed else 0
