"""``merlion bench enhance``: enhancer speed, image quality on reference pairs, and fish/no-fish separation."""

from __future__ import annotations

import argparse
import json

from companion.commands.enhance import add_enhancer_options, enhancer_config


def run(args: argparse.Namespace) -> int:
    from companion.bench import enhance_bench as eb
    from companion.commands.arg_checks import require_positive
    from companion.vision.enhancers.factory import make_enhancer

    require_positive("--seconds", args.seconds)  # NaN never compares as elapsed: the timing loop never ended
    cfg = enhancer_config(args)
    enhancer = make_enhancer(cfg.enhance)
    loaded = eb.load_images(args.images)
    frames = [img for _, img in loaded] or eb.synthetic_murky_frames()
    live = eb.live_size(cfg)
    result: dict = {"method": enhancer.name, "enhancer": enhancer.describe(),
                    "images": len(loaded) or "synthetic", "live_size": list(live)}
    for key, size in (("256", (256, 256)), ("live", live)):
        fps, cpu_ms = eb.measure_speed(enhancer, frames, size, seconds=args.seconds)
        result[f"fps_{key}"] = round(fps, 2)
        result[f"cpu_ms_{key}"] = round(cpu_ms, 2)
        print(f"{enhancer.name}: {fps:.1f} frames/s at {size[0]}x{size[1]}{' (live)' if key == 'live' else ''}, "
              f"{cpu_ms:.1f} ms CPU per frame", flush=True)
    if loaded:
        result["no_reference"] = eb.no_reference_report(enhancer, frames)
        nr = result["no_reference"]
        print(f"images: UCIQE {nr['uciqe_raw']:.3f} -> {nr['uciqe_enhanced']:.3f}, "
              f"UIQM {nr['uiqm_raw']:.3f} -> {nr['uiqm_enhanced']:.3f}")
    if args.quality:
        q = eb.quality_report(enhancer, eb.read_pairs(args.quality))
        result["quality"] = q
        print(f"pairs ({q['pairs']}): PSNR {q['psnr_degraded']:.2f} -> {q['psnr_enhanced']:.2f} dB, "
              f"SSIM {q['ssim_degraded']:.3f} -> {q['ssim_enhanced']:.3f}, "
              f"UCIQE {q['uciqe_degraded']:.3f} -> {q['uciqe_enhanced']:.3f} (reference {q['uciqe_reference']:.3f}), "
              f"UIQM {q['uiqm_degraded']:.3f} -> {q['uiqm_enhanced']:.3f} (reference {q['uiqm_reference']:.3f})")
    if args.separation:
        from companion.vision.encoders.factory import make_encoder

        encoder_cfg = cfg.encoder if args.encoder is None else cfg.encoder.model_copy(update={"name": args.encoder})
        encoder = make_encoder(encoder_cfg)
        sep = eb.separation_report(encoder, cfg.queries, enhancer, eb.load_labelled(args.separation),
                                   tau_ses=cfg.enhance.tau_ses)
        result["separation"] = sep
        for name, r in sep.items():
            if isinstance(r, dict):
                print(f"separation {name} ({r['frames']} frames, {r['fish']} fish) with {sep['encoder']}: "
                      f"AUROC {r['raw']['auroc']} -> {r['enhanced']['auroc']}, "
                      f"score gap {r['raw']['gap']} -> {r['enhanced']['gap']}; "
                      f"kept fish/no-fish raw filter {r['filter_raw']['fish_kept']}/{r['filter_raw']['nofish_kept']}"
                      f", selective {r['filter_selective']['fish_kept']}/{r['filter_selective']['nofish_kept']}")
    if args.json:
        print(json.dumps(result))
    return 0


def register(add_command) -> None:
    p = add_command("enhance", "enhancer frames/s at 256x256 and live size; --quality pairs; --separation data",
                    group="bench")
    p.add_argument("images", metavar="IMAGES", nargs="*", help="images or folders to time on (default: synthetic)")
    add_enhancer_options(p)
    p.add_argument("--json", action="store_true", help="last line: one JSON object (fps_256, fps_live, ...)")
    p.add_argument("--seconds", type=float, default=3.0, help="timing length per size (default 3)")
    p.add_argument("--quality", metavar="DIR", help="EUVP-style pairs folder (A/, GTr_A/): PSNR, SSIM, UCIQE, UIQM")
    p.add_argument("--separation", metavar="DATA_DIR",
                   help="shared data folder (suim/, survey/): fish/no-fish AUROC and score gap, raw vs enhanced")
    p.add_argument("--encoder", choices=("auto", "clip", "imagenet", "visual"),
                   help="encoder for --separation (default: encoder.name)")
    p.set_defaults(func=run)
