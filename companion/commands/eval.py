"""``merlion eval ...``: SRUM, the paper's Table I, label-based scores, AUROC and MERLION-vs-baseline."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from companion.commands.eval_setup import eval_config, make_encoder
from companion.commands.eval_sources import auroc_by_source, cmd_train_head
from companion.errors import MerlionError, UsageError

GROUP = "eval"
GROUP_HELP = "evaluate summaries: SRUM, Table I, labels, AUROC, comparison with the visual baseline"


def _srum_options(p: argparse.ArgumentParser, fps_default: str) -> None:
    p.add_argument("--alpha", type=float, default=0.5, help="weight of the label match (paper: 0.5)")
    p.add_argument("--tau", type=float, default=2.0, help="seconds of full time credit (paper: 2)")
    p.add_argument("--fps", type=float, default=None, help=f"frame rate of the label numbering ({fps_default})")


def _summary_options(p: argparse.ArgumentParser, runs: bool = False) -> None:
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--summary", type=int, nargs="+", metavar="FRAME", help="summary frames, 1-based")
    g.add_argument("--summary-json", metavar="PATH", help="a summary.json (or its folder) from merlion summarize")
    if runs:
        g.add_argument("--run", help="a stored automatic summary of the data set JSON (e.g. merlion, rost_trial_A)")
    p.add_argument("--label-fps", type=float, default=None,
                   help="map summary.json entries by time_s at this rate instead of by source index")


def _report_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--report", metavar="DIR", help="write an HTML report here")
    p.add_argument("--video", help="with --report and --summary-json: score every frame of this video with the "
                                   "summary's encoder and queries, for the score-over-time plot")
    p.add_argument("--config", help="YAML configuration for --video (encoder settings)")


def register(add_command) -> None:
    p = add_command("srum", "SRUM of a summary against human summaries (the paper's metric)", group=GROUP,
                    group_help=GROUP_HELP)
    p.add_argument("--labels", required=True, help="data set JSON (../shared/data/srum/*.json) or label CSV")
    _summary_options(p, runs=True)
    p.add_argument("--humans", help="human summaries: JSON {id: [frames]} or one summary per line "
                                    "(default for a data set JSON: its paper_table_human_ids)")
    _srum_options(p, "default: the data set's, else 30")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _report_options(p)
    p.set_defaults(func=_cmd_srum)

    p = add_command("table", "recompute the paper's Table I beside its printed values", group=GROUP)
    p.add_argument("--data", metavar="DIR", help="folder of data set JSONs (default ../shared/data/srum)")
    p.add_argument("--json", action="store_true", help="print {dataset: {column: value}}")
    p.set_defaults(func=_cmd_table)

    p = add_command("labels", "precision, coverage and SRUM vs an oracle for a video with per-frame labels",
                    group=GROUP)
    p.add_argument("--labels", required=True, help="label CSV (frame,labels or frame_index,...,fish_present)")
    _summary_options(p)
    p.add_argument("--query", help="the label that counts as relevant (default: fish when present, else any)")
    p.add_argument("--k", type=int, help="oracle summary size (default: the summary's size)")
    _srum_options(p, "default: 30; the survey video is 10")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _report_options(p)
    p.set_defaults(func=_cmd_labels)

    p = add_command("auroc", "how well the semantic score ranks labelled positive frames over negatives",
                    group=GROUP)
    p.add_argument("video", nargs="?", help="the labelled video (or --data for the shared data by source)")
    p.add_argument("--labels", help="label CSV, one row per source frame (with VIDEO)")
    p.add_argument("--data", metavar="DIR", help="the shared data folder (../shared/data): AUROC per source and "
                                                 "pooled over its labelled frames")
    p.add_argument("--stress", action="store_true",
                   help="with --data: add a synthetic murky green-cast copy of every frame (sources NAME~murky)")
    p.add_argument("--sweep", action="store_true",
                   help="with --data: the packaged encoder's settings, leave-one-group-out (slow: 6 encoder passes)")
    p.add_argument("--holdout", action="store_true",
                   help="with --data: a learned head (the fish head) is retrained without each group and scores "
                        "that group, so no figure comes from a group the head learned from; also the head's score "
                        "centred by each dive's running mean, every choice nested (slow: tens of minutes on 2 cores)")
    p.add_argument("--marks", type=int, metavar="N", help="with --data: in each group the first N positive and N "
                                                          "negative frames become marks; the rest are scored with "
                                                          "and without them (with --holdout: by the held-out head)")
    p.add_argument("--orders", type=int, metavar="N",
                   help="with --holdout or --marks: frame orders (seeds 0..N-1) each dive is streamed in; the scene "
                        "residual and the marks depend on the order, so their figures are given per order and "
                        "summarised over all (default 3)")
    p.add_argument("--config", help="YAML configuration (encoder and queries)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="override encoder.name")
    p.add_argument("--query", metavar="LABEL",
                   help="a label name, not a text query as elsewhere: the label that counts as positive (default: "
                        "fish when present, else any); the text queries come from --config")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_auroc)

    p = add_command("train-head", "train the packaged encoder's learned fish head on the shared data's labelled "
                    "frames (strength chosen leave-one-group-out) and print its held-out AUROC", group=GROUP)
    p.add_argument("--data", required=True, metavar="DIR", help="the shared data folder (../shared/data)")
    p.add_argument("--out", metavar="FILE", help="write the head here (the shipped one: "
                                                 "companion/vision/encoders/heads/fish.json)")
    p.add_argument("--scene-out", metavar="FILE", help="also train the head on the scene residual and write it here "
                   "(the shipped one: companion/vision/encoders/heads/fish-scene.json)")
    p.add_argument("--nested", action="store_true",
                   help="also report each group with the strength chosen without it (slow: one SVD per inner fold)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_train_head)

    p = add_command("feedback", "AUROC with and without the operator's marks: the first N positive and N "
                    "negative items become marks, the rest are scored", group=GROUP)
    p.add_argument("items", metavar="IMAGES", nargs="+",
                   help="images or folders (name order), or one video (frame order)")
    p.add_argument("--labels", required=True,
                   help="CSV: image name (or 0-based frame_index) first, then a *_present or label column")
    p.add_argument("--marks", type=int, required=True, metavar="N", help="marks per class (0: the query alone)")
    p.add_argument("--config", help="YAML configuration (encoder and queries)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet"], help="override encoder.name")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_feedback)

    p = add_command("compare", "summarize one video with MERLION and with the visual baseline; score both",
                    group=GROUP)
    p.add_argument("video", help="the labelled video")
    p.add_argument("--labels", required=True, help="label CSV, one row per source frame")
    p.add_argument("--config", help="YAML configuration (MERLION's encoder, queries, sampler)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet"], help="MERLION's encoder (override)")
    p.add_argument("--query", help="the label that counts as relevant (default: fish when present, else any)")
    p.add_argument("--out", metavar="DIR", help="keep both summaries here (default: a temporary folder)")
    p.add_argument("--no-scores", action="store_true",
                   help="skip MERLION's full-rate scoring pass (no AUROC, no score plot; half the time)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--report", metavar="DIR", help="write an HTML report here")
    p.set_defaults(func=_cmd_compare)


def _params(args: argparse.Namespace, fps: float | None):
    from companion.evaluation.srum import SrumParams

    return SrumParams(alpha=args.alpha, tau_s=args.tau, fps=args.fps or fps or 30.0)


def _summary_frames(args: argparse.Namespace) -> tuple[list[int], dict | None, Path | None]:
    """The summary's frames; also checks the numeric options first, since every summary command starts here."""
    from companion.commands.arg_checks import require_positive
    from companion.evaluation.datasets import read_summary_json

    require_positive("--fps", args.fps)
    require_positive("--label-fps", args.label_fps)
    k = getattr(args, "k", None)  # only eval labels has --k
    if k is not None and k < 1:
        raise UsageError(f"--k {k}: must be at least 1")
    if getattr(args, "run", None):
        return [], None, None
    if args.summary_json:
        frames, data = read_summary_json(args.summary_json, args.label_fps)
        path = Path(args.summary_json)
        return frames, data, path if path.is_dir() else path.parent
    return list(args.summary), None, None


def _cmd_srum(args: argparse.Namespace) -> int:
    from companion.evaluation import srum as m
    from companion.evaluation.datasets import load_dataset, load_humans, load_labels

    frames, summary, base = _summary_frames(args)
    if Path(args.labels).suffix.lower() == ".json":
        ds = load_dataset(args.labels)
        table = ds.table
        humans = load_humans(args.humans) if args.humans else ds.paper_humans()
        if args.run:
            if args.run not in ds.automatic:
                raise UsageError(f"--run {args.run}: not in {args.labels} (runs: {', '.join(ds.automatic)})")
            frames = ds.automatic[args.run]
    else:
        if args.run:
            raise UsageError("--run needs a data set JSON as --labels")
        if not args.humans:
            raise UsageError("--humans FILE is needed with a CSV label file (a data set JSON carries its own)")
        table = load_labels(args.labels, args.fps)
        humans = load_humans(args.humans)
    params = _params(args, table.fps)
    value = m.srum(frames, humans, table.labels, params)
    # the leave-one-out human score needs two people; with one, SRUM alone is still meaningful
    human = m.human_score(humans, table.labels, params) if len(humans) >= 2 else None
    result = {"srum": value, "human": human, "relative": None if human is None else m.relative(value, human),
              "frames": frames, "humans": len(humans), "alpha": params.alpha, "tau": params.tau_s, "fps": params.fps}
    if args.json:
        print(json.dumps(result))
    else:
        versus = "human n/a (one human summary)" if human is None else (
            f"human {human:.4f}  relative {result['relative']:.1f}%")
        print(f"SRUM {value:.4f}  {versus}  "
              f"({len(humans)} human summaries; alpha {params.alpha:g}, tau {params.tau_s:g} s, fps {params.fps:g})")
    if args.report:
        _report(args, "SRUM", summary, base, result)
    return 0


def _report(args: argparse.Namespace, name: str, summary: dict | None, base: Path | None, metrics: dict) -> None:
    from companion.evaluation.report import ReportRun, write_report
    from companion.evaluation.runs import attach_scores, run_from_summary, summary_config

    shown = {k: v for k, v in metrics.items() if not isinstance(v, dict)}
    if summary is not None and base is not None:
        run = run_from_summary(name, summary, base, shown)
        if args.video:
            cfg = summary_config(summary, eval_config(args, None))
            attach_scores(run, args.video, cfg, make_encoder(cfg))
    else:
        if args.video:
            raise UsageError("--video needs --summary-json (the encoder and queries come from it)")
        run = ReportRun(name=name, metrics=shown)
    page = write_report(args.report, [run], title=f"MERLION evaluation: {name}")
    print(f"report: {page}")


def default_data_dir() -> Path:
    """../shared/data/srum beside the current folder, else beside the repository."""
    repo = Path(__file__).resolve().parents[2]
    for base in (Path.cwd(), repo):
        candidate = base.parent / "shared" / "data" / "srum"
        if candidate.is_dir():
            return candidate
    raise UsageError("SRUM data not found at ../shared/data/srum (beside the current folder or the repository); "
                     "pass --data DIR")


def _cmd_table(args: argparse.Namespace) -> int:
    from companion.evaluation.table import compute_table, format_table, table_json

    cells = compute_table(Path(args.data) if args.data else default_data_dir())
    if args.json:
        print(json.dumps(table_json(cells)))
    else:
        print(format_table(cells))
    bad = [c for c in cells if c.verdict == "mismatch"]
    if bad:
        raise MerlionError(f"{len(bad)} value(s) differ from the paper's Table I, first {bad[0].dataset} "
                           f"{bad[0].column}: {bad[0].ours:.6f} vs {bad[0].paper}")
    return 0


def _cmd_labels(args: argparse.Namespace) -> int:
    from companion.evaluation.datasets import load_labels
    from companion.evaluation.labels_eval import default_query, evaluate_labels

    frames, summary, base = _summary_frames(args)
    table = load_labels(args.labels, args.fps)
    query = args.query or default_query(table)
    if args.k is not None and not 1 <= args.k <= len(table.labels):  # a huge K never finished
        raise UsageError(f"--k {args.k}: must be from 1 to the {len(table.labels)} labelled frames of {args.labels}")
    result = evaluate_labels(table, frames, query, args.k, _params(args, table.fps)).as_dict()
    if args.json:
        print(json.dumps(result))
    else:
        print(f"precision {result['precision']:.3f}  coverage {result['coverage']:.3f} "
              f"({result['positive_segments']} positive segments)  label coverage {result['label_coverage']:.3f}  "
              f"SRUM vs oracle {result['srum_oracle']:.4f}  (query {query or 'any label'}; oracle {result['oracle']})")
    if args.report:
        _report(args, "summary", summary, base, result)
    return 0


def _cmd_auroc(args: argparse.Namespace) -> int:
    from companion.evaluation.auroc import auroc, threshold_rates
    from companion.evaluation.datasets import load_labels
    from companion.evaluation.frame_scores import score_video
    from companion.evaluation.labels_eval import default_query, is_positive

    if args.data:
        if args.video or args.labels:
            raise UsageError("--data scores the shared data by source: give it without VIDEO and --labels")
        return auroc_by_source(args)
    if not args.video or not args.labels:
        raise UsageError("eval auroc needs VIDEO --labels CSV, or --data DIR")
    if args.stress or args.sweep or args.marks is not None or args.holdout or args.orders is not None:
        raise UsageError("--stress, --sweep, --holdout, --marks and --orders go with --data")
    cfg = eval_config(args, args.encoder)
    table = load_labels(args.labels)
    query = args.query or default_query(table)
    encoder = make_encoder(cfg)
    vs = score_video(args.video, encoder, cfg.queries, cfg.encoder.batch)
    missing = [i + 1 for i in vs.indices if i + 1 not in table.labels]
    if missing:
        raise MerlionError(f"{args.labels}: no label for video frame {missing[0]} (1-based); "
                           f"the video has {len(vs.indices)} frames")
    beyond = [f for f in sorted(table.labels) if f > len(vs.indices)]
    if beyond:  # a truncated video, or another video's labels: scoring only what decoded would hide it
        raise MerlionError(f"{args.video}: {len(vs.indices)} frames decoded, but {args.labels} labels frame "
                           f"{beyond[0]} (1-based) and {len(beyond) - 1} more after its end")
    positive = [is_positive(table, i + 1, query) for i in vs.indices]
    result = {"auroc": auroc(vs.scores, positive), "frames": len(positive), "positives": int(sum(positive)),
              "encoder": encoder.describe(), "query": query, "prompts": [cfg.queries.positive, *cfg.queries.negatives],
              "at_tau_ss": threshold_rates(vs.scores, positive, cfg.queries.tau_ss)}
    if args.json:
        print(json.dumps(result))
    else:
        t = result["at_tau_ss"]
        print(f"AUROC {result['auroc']:.4f}  ({result['positives']} positive of {result['frames']} frames; "
              f"encoder {encoder.name}; at tau_ss {t['tau']:g}: recall {t['recall']:.3f}, "
              f"false pass {t['false_pass']:.3f})")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from companion.evaluation.compare import compare, format_compare

    cfg = eval_config(args, args.encoder)
    result = compare(args.video, args.labels, cfg, make_encoder, query=args.query, out_dir=args.out,
                     report_dir=args.report, scores=not args.no_scores)
    print(json.dumps(result) if args.json else format_compare(result))
    if args.report:
        print(f"report: {Path(args.report) / 'index.html'}")
    return 0


def _labelled_items(paths: list[str], labels: dict[str, bool], labels_path: str) -> tuple[list, list[bool], list[str]]:
    """(images, positive, names) in name order (images) or frame order (one video); every item needs a label."""
    import cv2

    from companion.sources.folder import IMAGE_SUFFIXES, collect_images

    one = Path(paths[0])
    if len(paths) == 1 and one.is_file() and one.suffix.lower() not in IMAGE_SUFFIXES:
        cap = cv2.VideoCapture(str(one))
        if not cap.isOpened():
            raise MerlionError(f"{one}: OpenCV cannot open this video")
        images, names, kind = [], [], "frame index"
        while True:
            ok, img = cap.read()
            if not ok:
                break
            images.append(img)
            names.append(str(len(names)))
        cap.release()
    else:
        files = collect_images(paths)
        names, kind = [f.name for f in files], "image"
        images = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in files]
        bad = [f for f, img in zip(files, images, strict=True) if img is None]
        if bad:
            raise MerlionError(f"{bad[0]}: cannot decode as an image")
    if not images:
        raise MerlionError(f"{paths[0]}: no frames could be decoded")
    missing = [n for n in names if n not in labels]
    if missing:
        raise MerlionError(f"--labels {labels_path}: no label for {kind} {missing[0]}")
    return images, [labels[n] for n in names], names


def _cmd_feedback(args: argparse.Namespace) -> int:
    import numpy as np  # 0.07-0.1 s measured: only for this command, not for every merlion call

    from companion.evaluation.feedback_eval import evaluate, read_item_labels, split_marks
    from companion.vision.presampler import PreSampler

    if args.marks < 0:
        raise UsageError(f"--marks {args.marks}: must be 0 or more")
    labels = read_item_labels(args.labels)
    images, positive, _ = _labelled_items(args.items, labels, args.labels)
    split_marks(positive, args.marks)  # refuse an impossible --marks before loading the encoder
    cfg = eval_config(args, args.encoder)
    encoder = make_encoder(cfg)
    presampler = PreSampler(encoder, cfg.queries.positive, cfg.queries.negatives, cfg.queries.tau_ss)
    embeddings = np.concatenate([encoder.encode_images(images[i:i + cfg.encoder.batch])
                                 for i in range(0, len(images), cfg.encoder.batch)])
    result = evaluate(encoder, presampler, embeddings, positive, args.marks).as_dict()
    result["encoder"] = encoder.name
    if args.json:
        print(json.dumps(result))
    else:
        print(f"AUROC query alone {result['auroc_query']:.4f}  with {args.marks} + {args.marks} marks "
              f"{result['auroc_marked']:.4f}  ({result['positives']} positive of {result['scored']} scored; "
              f"encoder {encoder.name})")
    return 0
