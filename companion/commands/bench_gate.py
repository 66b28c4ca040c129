"""``merlion bench gate``: gated against ungated summaries on every shared video (SRUM, segments, precision, speed)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(add_command) -> None:
    p = add_command("gate", "does the frame gate keep the summary's spread? gated vs ungated on every video",
                    group="bench")
    p.add_argument("--data", metavar="DIR", default="../shared/data",
                   help="the shared test data folder (default ../shared/data)")
    p.add_argument("--case", action="append", metavar="TEXT",
                   help="only cases whose name contains TEXT (repeatable), e.g. --case survey")
    p.add_argument("--encoder", choices=["auto", "clip", "imagenet", "visual"], help="which encoder (default auto)")
    p.add_argument("--threshold", type=float, default=0.0, metavar="TAU",
                   help="semantic pre-sampling threshold tau_ss (default 0: no semantic gate)")
    p.add_argument("--gate-threshold", type=float, metavar="GREY", help="gate: mean absolute difference to encode")
    p.add_argument("--gate-max-gap", type=float, metavar="S", help="gate: encode at least every S seconds")
    p.add_argument("--gate-max-share", type=float, metavar="SHARE",
                   help="gate: encode once this share of the frames seen so far has passed (0: off)")
    p.add_argument("--config", metavar="FILE", help="YAML configuration; the options above override it")
    p.add_argument("--json", action="store_true", help="end with one JSON object on the last line")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.bench.gate_bench import compare_case, default_cases, table_head, table_row
    from companion.config import load_config
    from companion.errors import UsageError
    from companion.vision.encoders.factory import make_encoder

    data = Path(args.data)
    if not data.is_dir():
        raise UsageError(f"--data {data}: no such folder")
    over: dict = {"queries": {"tau_ss": args.threshold}}
    if args.encoder:
        over["encoder"] = {"name": args.encoder}
    gate = {"mode": "difference", "threshold": args.gate_threshold, "max_gap_s": args.gate_max_gap,
            "max_gap_share": args.gate_max_share}
    over["gate"] = {k: v for k, v in gate.items() if v is not None}
    cfg = load_config(args.config, overrides=over)
    cases = [c for c in default_cases(data) if not args.case or any(t.lower() in c.name.lower() for t in args.case)]
    if not cases:
        raise UsageError(f"--case {', '.join(args.case or [])}: no such case in {data}")
    encoder = make_encoder(cfg.encoder)
    g = cfg.gate
    print(f"gate: difference > {g.threshold:g}, max gap {g.max_gap_s:g} s, share {g.max_gap_share:g}; "
          f"tau_ss {cfg.queries.tau_ss:g}; K {cfg.sampler.k}; encoder {encoder.name}")
    print(table_head(), flush=True)
    rows = []
    for case in cases:  # a row as soon as its case is done: the whole table takes minutes
        rows.append(compare_case(cfg, case, encoder))
        print(table_row(rows[-1]), flush=True)
    if args.json:
        print(json.dumps({"gate": g.model_dump(), "rows": rows}))
    return 0
