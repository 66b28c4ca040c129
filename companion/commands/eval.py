"""``merlion eval ...``: SRUM, the paper's Table I, label-based scores, AUROC and MERLION-vs-baseline."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from companion.errors import MerlionError, UsageError
from companion.output_path import check_target

if TYPE_CHECKING:
    from companion.evaluation.pasted_fish import PastedFish
    from companion.evaluation.sources import LabelledFrame
    from companion.vision.encoders.imagenet import ImageNetEncoder

GROUP = "eval"
GROUP_HELP = "evaluate summaries: SRUM, Table I, labels, AUROC, comparison with the visual baseline"
MAX_ORDERS = 50
"""Frame orders ``eval auroc --orders`` takes: each costs about 20 s per protocol on two cores."""


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
                        "centred by each dive's running mean, every choice nested")
    p.add_argument("--marks", type=int, metavar="N", help="with --data: in each group the first N positive and N "
                                                          "negative frames become marks; the rest are scored with "
                                                          "and without them (with --holdout: by the held-out head)")
    p.add_argument("--orders", type=int, metavar="N",
                   help="with --holdout or --marks: frame orders (seeds 0..N-1) each dive is streamed in; the scene "
                        "residual and the marks depend on the order, so their figures are given per order and "
                        "summarised over all (default 3)")
    p.add_argument("--config", help="YAML configuration (encoder and queries)")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="override encoder.name")
    p.add_argument("--query", help="the label that counts as positive (default: fish when present, else any)")
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
    p.set_defaults(func=_cmd_train_head)

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
            cfg = summary_config(summary, _config(args, None))
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


def _config(args: argparse.Namespace, encoder: str | None):
    from companion.config import load_config

    overrides = {"encoder": {"name": encoder}} if encoder else None
    return load_config(args.config, overrides=overrides)


def make_encoder(cfg):
    """The configured encoder: the team's factory, with the visual baseline always available."""
    if cfg.encoder.name == "visual":
        from companion.vision.encoders.visual import VisualEncoder

        return VisualEncoder(cfg.encoder)
    try:
        from companion.vision.encoders.factory import make_encoder as factory
    except ImportError:
        raise MerlionError(f"encoder {cfg.encoder.name!r}: companion.vision.encoders.factory is not installed") from None
    return factory(cfg.encoder)


def _cmd_auroc(args: argparse.Namespace) -> int:
    from companion.evaluation.auroc import auroc, threshold_rates
    from companion.evaluation.datasets import load_labels
    from companion.evaluation.frame_scores import score_video
    from companion.evaluation.labels_eval import default_query, is_positive

    if args.data:
        if args.video or args.labels:
            raise UsageError("--data scores the shared data by source: give it without VIDEO and --labels")
        return _auroc_by_source(args)
    if not args.video or not args.labels:
        raise UsageError("eval auroc needs VIDEO --labels CSV, or --data DIR")
    if args.stress or args.sweep or args.marks is not None or args.holdout or args.orders is not None:
        raise UsageError("--stress, --sweep, --holdout, --marks and --orders go with --data")
    cfg = _config(args, args.encoder)
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

    cfg = _config(args, args.encoder)
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
    from companion.evaluation.feedback_eval import evaluate, read_item_labels, split_marks
    from companion.vision.presampler import PreSampler

    if args.marks < 0:
        raise UsageError(f"--marks {args.marks}: must be 0 or more")
    labels = read_item_labels(args.labels)
    images, positive, _ = _labelled_items(args.items, labels, args.labels)
    split_marks(positive, args.marks)  # refuse an impossible --marks before loading the encoder
    cfg = _config(args, args.encoder)
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


def _auroc_by_source(args: argparse.Namespace) -> int:
    """Per-source and pooled AUROC of the configured encoder on the shared data; --sweep: held-out choices."""
    from companion.evaluation.dive_centring import ORDER_SEEDS, stream_order
    from companion.evaluation.head_training import held_out_head
    from companion.evaluation.holdout import leave_one_group_out, per_group, per_source, spread
    from companion.evaluation.pasted_fish import fish_crops
    from companion.evaluation.sources import DEEPFISH, load_sources
    from companion.vision.presampler import PreSampler

    if args.marks is not None and args.marks < 1:  # before minutes of loading
        raise UsageError(f"--marks {args.marks}: must be 1 or more")
    if args.orders is not None and not 1 <= args.orders <= MAX_ORDERS:
        raise UsageError(f"--orders {args.orders}: must be 1 to {MAX_ORDERS}")
    if args.orders is not None and not (args.holdout or args.marks):
        raise UsageError("--orders goes with --holdout or --marks (the figures that depend on the frame order)")
    seeds = ORDER_SEEDS if args.orders is None else tuple(range(args.orders))
    frames = load_sources(args.data, stress=args.stress)
    cfg = _config(args, args.encoder)
    encoder = make_encoder(cfg)
    presampler = PreSampler(encoder, cfg.queries.positive, cfg.queries.negatives, cfg.queries.tau_ss)
    batch = cfg.encoder.batch
    # the held-out scene head that answers the query also learns from pasted fish: their boxes are read first
    scene_head = encoder.scene_head_of(presampler.text_embeddings) if hasattr(encoder, "scene_head_of") else None
    crops = fish_crops(args.data) if args.holdout and scene_head is not None else []
    scores = np.zeros(len(frames), dtype=np.float32)
    embeddings: np.ndarray | None = None
    done = 0
    for stream in stream_order(frames):  # each source is one dive, scored in its own order
        presampler.new_dive()
        for i in range(0, len(stream), batch):
            idx = stream[i:i + batch]
            emb = encoder.encode_images([frames[j].image for j in idx])
            if embeddings is None:
                embeddings = np.zeros((len(frames), emb.shape[1]), dtype=emb.dtype)
            embeddings[idx] = emb
            scores[idx] = presampler.scores(emb)
            done += len(idx)
            if done % 100 < len(idx) or done == len(frames):
                _progress(f"encoding: {done} of {len(frames)} frames")
    features = encoder.sampler_features(embeddings)
    pasted = _pasted(encoder, frames, crops) if crops else None
    result: dict = {"encoder": encoder.describe(), "frames": len(frames), "auroc": per_source(scores, frames)}
    result["by_group"] = per_group(scores, frames)
    result["deepfish_habitats"] = spread(result["by_group"], DEEPFISH)
    if args.holdout:
        result["holdout"] = held_out_head(encoder, presampler, features, frames)
        if result["holdout"]["by_group"]:
            from companion.evaluation.dive_centring import held_out_centred

            result["dive_centred"] = held_out_centred(features, frames)
            if hasattr(encoder, "scene_of"):  # the scene head's input: the region views and small frames
                from companion.evaluation.scene_holdout import held_out_scene

                scene = encoder.scene_of(embeddings)
                result["scene"] = held_out_scene(scene, frames, seeds, pasted=pasted,
                                                 progress=lambda m: _progress(f"scene head, {m}"))
                if any(f.clip for f in frames):  # the same, with no change of clip inside a dive
                    result["scene_by_clip"] = held_out_scene(
                        scene, frames, seeds, pasted=pasted, by_clip=True,
                        progress=lambda m: _progress(f"scene head, each clip a dive, {m}"))
    if args.marks:
        from companion.evaluation.group_feedback import marks_by_group

        result["marks"] = marks_by_group(encoder, presampler, embeddings, frames, args.marks,
                                         held_out=args.holdout, seeds=seeds, pasted=pasted,
                                         progress=lambda m: _progress(f"marks, {m}"))
    if args.sweep:
        from companion.evaluation.encoder_sweep import sweep

        variants = sweep(frames, progress=lambda name: _progress(f"sweep: {name}"))
        result["variants"] = {name: per_source(s, frames) for name, s in variants.items()}
        result["leave_one_group_out"] = leave_one_group_out(variants, frames)
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"encoder {encoder.name}, {len(frames)} frames")
    for source, value in result["auroc"].items():
        print(f"  {source:24s} AUROC {value:.3f}")
    for name in ("deepfish_habitats",):
        d = result[name]
        if d:
            print(f"DeepFish habitats: mean {d['mean']:.3f} min {d['min']:.3f} max {d['max']:.3f} "
                  f"spread {d['spread']:.3f} ({d['groups']} habitats)")
    if "holdout" in result:
        h = result["holdout"]
        print(f"held out ({h['method']}):")
        for group, value in h["by_group"].items():
            print(f"  {group:24s} AUROC {value:.3f}")
        d = h["deepfish_habitats"]
        if d:
            print(f"  DeepFish habitats held out: mean {d['mean']:.3f} min {d['min']:.3f} max {d['max']:.3f} "
                  f"spread {d['spread']:.3f}")
    if "dive_centred" in result:
        c = result["dive_centred"]
        print(f"held out, dive-centred ({c['method']}):")
        for group, value in c["by_group"].items():
            choice = c["chosen"].get(group)
            note = f"  (lambda {choice['lambda']:g}, prior weight {choice['prior_weight']})" if choice else ""
            print(f"  {group:24s} AUROC {value:.3f}{note}")
        d = c["deepfish_habitats"]
        if d:
            print(f"  DeepFish habitats held out: mean {d['mean']:.3f} min {d['min']:.3f} max {d['max']:.3f} "
                  f"spread {d['spread']:.3f}; DeepFish pooled {c['deepfish_pooled']:.3f}")
    for key in ("scene", "scene_by_clip"):
        if key in result:
            _print_scene(result[key])
    if "marks" in result:
        m = result["marks"]
        print(f"{m['marks']} + {m['marks']} marks from each group's first frames in its dive's order (seed "
              f"{m['seed']}){' (held-out head)' if m['held_out'] else ''}; centred marks' weight chosen without "
              f"each group (on all groups: {m['weight']}):")
        for group, r in m["groups"].items():
            print(f"  {group:24s} query {r['auroc_query']:.3f}  marked {r['auroc_marked']:.3f}  "
                  f"gain {r['gain']:+.3f}  trust {r['centred_trust']:.2f}  weight {r['weight']:g}")
        for seed, o in m["orders"].items():
            if o["groups"]:
                print(f"  order seed {seed}: mean gain {o['mean_gain']:+.3f}  worst {o['worst_gain']:+.3f}  "
                      f"mean AUROC {o['mean_query']:.3f} -> {o['mean_marked']:.3f}")
        if len(m["orders"]) > 1 and m["over_orders"]:
            print("  over " + _orders_line(m["over_orders"]))
    for row in result.get("leave_one_group_out", []):
        print(f"held out {row['held_out']:10s} chosen {row['chosen']:40s} tune {row['tune_auroc']:.3f}  "
              f"held-out {row['held_out_auroc']:.3f}")
    return 0


def _progress(message: str) -> None:
    """One line on stderr: the held-out figures take minutes to an hour, and stdout may be the JSON."""
    print(message, file=sys.stderr, flush=True)


def _orders_line(summary: dict) -> str:
    """One line: each figure's mean and range over the frame orders."""
    n = next(iter(summary.values()))["orders"]
    return f"{n} orders: " + ", ".join(f"{name.replace('_', ' ')} {v['mean']:.3f} ({v['min']:.3f}-{v['max']:.3f})"
                                       for name, v in summary.items())


def _print_scene(c: dict) -> None:
    print(f"held out, scene residual ({c['method']}):")
    for name, o in [("pooled head", c["pooled_head"])] + [(f"order seed {k}", o) for k, o in c["orders"].items()]:
        d = o["deepfish_habitats"]
        print(f"  {name:16s} group mean {o['group_mean']:.3f}  pooled {o['pooled']:.3f}  DeepFish habitats mean "
              f"{d['mean']:.3f} min {d['min']:.3f}  DeepFish pooled {o['deepfish_pooled']:.3f}")
    if len(c["orders"]) > 1:
        print("  over " + _orders_line(c["over_orders"]))
    first = next(iter(c["orders"].values()), None)
    if first:
        print("  per group (pooled head -> scene head, first order): " + ", ".join(
            f"{g} {c['pooled_head']['by_group'][g]:.2f} -> {v:.2f}" for g, v in first["by_group"].items()))


def _pasted(encoder: ImageNetEncoder, frames: Sequence[LabelledFrame], crops: list[np.ndarray]) -> PastedFish:
    """The scene head's extra training frames (``pasted_fish``), encoded, with a line on stderr: it takes a while."""
    from companion.evaluation.pasted_fish import pasted_fish

    _progress("scene head: encoding empty DeepFish frames with fish pasted in")
    return pasted_fish(encoder, frames, crops)


def _cmd_train_head(args: argparse.Namespace) -> int:
    from companion.config import EncoderConfig
    from companion.evaluation.head_training import frame_scenes, nested_holdout, train_head
    from companion.evaluation.holdout import per_group, spread
    from companion.evaluation.pasted_fish import fish_crops
    from companion.evaluation.scene_holdout import train_scene_head
    from companion.evaluation.sources import DEEPFISH, load_sources
    from companion.vision.encoders.imagenet import ImageNetEncoder

    for out in (args.out, args.scene_out):  # before the long encoding: a bad path fails at once
        if out:
            check_target(out)
    frames = load_sources(args.data)
    crops = fish_crops(args.data) if args.scene_out else []  # before the long encoding: no boxes, no wait
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"), heads=False)
    classes = np.flatnonzero(encoder.encode_texts(["fish"])[0, :1000] > 0)
    scene = frame_scenes(encoder, frames)
    features = np.ascontiguousarray(scene.views[:, 0])
    head, figures = train_head(frames, features, concept="fish", classes=classes)
    if args.scene_out:
        pasted = _pasted(encoder, frames, crops)
        scene_head, scene_figures = train_scene_head(frames, scene, concept="fish", classes=classes, pasted=pasted)
        figures["scene"] = {**scene_figures, "deepfish_habitats": spread(scene_figures["groups"], DEEPFISH),
                            "file": str(scene_head.save(args.scene_out))}
    figures["deepfish_habitats"] = spread(figures["groups"], DEEPFISH)
    if args.nested:
        y = np.array([f.fish for f in frames])
        scores, chosen = nested_holdout(features, y, np.array([f.group for f in frames]))
        groups = per_group(scores, frames)
        figures["nested"] = {"groups": groups, "lambda": chosen, "deepfish_habitats": spread(groups, DEEPFISH)}
    if args.out:
        figures["file"] = str(head.save(args.out))
    if args.json:
        print(json.dumps(figures))
        return 0
    d = figures["deepfish_habitats"]
    print(f"fish head: {len(frames)} frames, lambda {figures['lambda']:g}; leave-one-group-out: group mean AUROC "
          f"{figures['group_mean_auroc']:.3f}, pooled {figures['pooled_auroc']:.3f}; DeepFish habitats mean "
          f"{d['mean']:.3f} min {d['min']:.3f} max {d['max']:.3f}")
    for g, v in figures["groups"].items():
        print(f"  held out {g:20s} AUROC {v:.3f}")
    if "file" in figures:
        print(f"head: {figures['file']}")
    if "scene" in figures:
        c = figures["scene"]
        d = c["deepfish_habitats"]
        print(f"scene head: lambda {c['lambda']:g}; leave-one-group-out: group "
              f"mean AUROC {c['group_mean_auroc']:.3f}, pooled {c['pooled_auroc']:.3f}; DeepFish habitats mean "
              f"{d['mean']:.3f} min {d['min']:.3f}; head: {c['file']}")
    return 0
