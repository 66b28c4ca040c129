"""``merlion models pull|list``: get CLIP weights onto a machine, and see which encoders can run offline."""

from __future__ import annotations

import argparse

_GROUP_HELP = "CLIP weights: download them where a network exists, list what is available offline"


def register(add_command) -> None:
    p = add_command("pull", "download and verify CLIP weights into the local cache (needs a network)",
                    group="models", group_help=_GROUP_HELP)
    p.add_argument("name", nargs="?", metavar="NAME",
                   help="open_clip architecture, optionally ARCH:TAG (default ViT-B-32)")
    p.add_argument("--pretrained", metavar="TAG", help="pretrained tag (default: the configured one for ViT-B-32, "
                                                       "else the architecture's first tag)")
    p.add_argument("--cache-dir", metavar="DIR", help="download here instead of open_clip's default cache")
    p.set_defaults(func=run_pull)
    p = add_command("list", "list the encoders and CLIP weights usable offline", group="models")
    p.add_argument("--all", action="store_true", help="also list every architecture:tag open_clip knows")
    p.set_defaults(func=run_list)


def _name_and_tag(name: str | None, tag: str | None) -> tuple[str, str]:
    import open_clip

    # pydantic: 0.15-0.25 s measured, not for every merlion call (the default NAME is read here, not in register)
    from companion.config import EncoderConfig

    name = name or EncoderConfig().model
    if ":" in name and tag is None:
        name, tag = name.split(":", 1)
    if tag is None:
        default = EncoderConfig()
        tags = open_clip.list_pretrained_tags_by_model(name)
        tag = default.pretrained if name == default.model and default.pretrained else (tags[0] if tags else "")
    return name, tag


def run_pull(args: argparse.Namespace) -> int:
    from companion.vision.encoders.weights import pull

    model, tag = _name_and_tag(args.name, args.pretrained)
    path = pull(model, tag, cache_dir=args.cache_dir)
    print(f"{model} ({tag}) verified: {path}")
    print(f"use it offline with: --encoder clip --model {model} --weights {path}")
    return 0


def run_list(args: argparse.Namespace) -> int:
    import open_clip

    from companion.vision.encoders.weights import list_cached

    print("imagenet\tefficientnet-lite0\tpackaged (always available)")
    cached = list_cached()
    for model, tag, path in cached:
        print(f"clip\t{model}:{tag}\t{path}")
    if not cached:
        print("clip\t(no cached weights: `merlion models pull` where a network exists, or pass --weights PATH)")
    if args.all:
        for model, tag in open_clip.list_pretrained():
            print(f"known\t{model}:{tag}")
    return 0
