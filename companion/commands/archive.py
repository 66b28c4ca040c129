"""``merlion archive SOURCES... --out DIR``: summarize a campaign of dives on Ray, tagged from the dive logs."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.commands.overrides import Overrides, put, put_queries_and_encoder
from companion.config import load_config
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
    p.add_argument("-k", "--k", type=int, help="summary size (default 6)")
    p.add_argument("--query", metavar="TEXT", help="positive query (default: 'underwater image with fish')")
    p.add_argument("--negative", metavar="TEXT", action="append", help="negative query, repeatable")
    p.add_argument("--threshold", type=float, metavar="TAU", help="pre-sampling threshold tau_ss")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="which encoder scores frames")
    p.add_argument("--model", help="open_clip architecture for --encoder clip (default ViT-B-32)")
    p.add_argument("--weights", metavar="PATH", help="local CLIP checkpoint file (on every worker)")
    p.add_argument("--fps", type=float, help="frames per second kept from each source (default 5)")
    p.add_argument("--enhance", choices=["none", "always", "selective"], help="MERLION-E enhancement mode")
    p.add_argument("--batch", type=int, help="frames encoded together (default 8)")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report and frame index")
    p.set_defaults(func=run)


def overrides_from(args: argparse.Namespace) -> Overrides:
    over: Overrides = {}
    put(over, "source", "fps", args.fps)
    put(over, "sampler", "k", args.k)
    put(over, "queries", "tau_ss", args.threshold)
    put(over, "enhance", "mode", args.enhance)
    put_queries_and_encoder(over, args)
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
    cfg = load_config(args.config, overrides=overrides_from(args))
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
