"""``merlion eval auroc --data`` and ``merlion eval train-head``: the fish heads' figures on the shared labelled
sources, every choice made without the group it is reported on."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from companion.commands.eval_setup import eval_config, make_encoder
from companion.errors import UsageError
from companion.output_path import check_target

if TYPE_CHECKING:
    import numpy as np

    from companion.evaluation.pasted_fish import PastedFish
    from companion.evaluation.sources import LabelledFrame
    from companion.vision.encoders.imagenet import ImageNetEncoder

MAX_ORDERS = 50
"""Frame orders ``eval auroc --orders`` takes: each costs about 20 s per protocol on two cores."""


def auroc_by_source(args: argparse.Namespace) -> int:
    """Per-source and pooled AUROC of the configured encoder on the shared data; --sweep: held-out choices."""
    import numpy as np  # 0.07-0.1 s measured: only for this command, not for every merlion call

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
    cfg = eval_config(args, args.encoder)
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
    if d := result["deepfish_habitats"]:
        print(f"DeepFish habitats: {_spread_text(d)} ({d['groups']} habitats)")
    if "holdout" in result:
        _print_held_out("held out", result["holdout"])
    if "dive_centred" in result:
        c = result["dive_centred"]
        notes = {g: f"  (lambda {choice['lambda']:g}, prior weight {choice['prior_weight']})"
                 for g, choice in c["chosen"].items() if choice}
        _print_held_out("held out, dive-centred", c, notes, f"; DeepFish pooled {c['deepfish_pooled']:.3f}")
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


def _print_held_out(title: str, h: dict, notes: dict[str, str] | None = None, tail: str = "") -> None:
    """One held-out result: its method, each group's AUROC (with its note), the DeepFish habitats' spread."""
    print(f"{title} ({h['method']}):")
    for group, value in h["by_group"].items():
        print(f"  {group:24s} AUROC {value:.3f}{(notes or {}).get(group, '')}")
    if d := h["deepfish_habitats"]:
        print(f"  DeepFish habitats held out: {_spread_text(d)}{tail}")


def _spread_text(d: dict) -> str:
    """A ``holdout.spread`` summary as printed."""
    return f"mean {d['mean']:.3f} min {d['min']:.3f} max {d['max']:.3f} spread {d['spread']:.3f}"


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


def cmd_train_head(args: argparse.Namespace) -> int:
    import numpy as np  # 0.07-0.1 s measured: only for this command, not for every merlion call

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
