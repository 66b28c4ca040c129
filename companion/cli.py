"""The ``merlion`` command: a thin layer that finds the subcommands and turns domain errors into exit codes.

Each module in ``companion.commands`` defines ``register(add_command)``; ``add_command(name, help, group=None)``
returns an argparse parser whose ``func`` default is called with the parsed arguments and returns an exit code.
Commands under a group (``merlion bench pipeline``, ``merlion eval srum``) share that group's parser, so a new
benchmark or metric is one new module and nothing else changes.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from collections.abc import Callable, Sequence

from companion import __version__, commands
from companion.config import ConfigError
from companion.errors import MerlionError

log = logging.getLogger("merlion")

AddCommand = Callable[..., argparse.ArgumentParser]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="merlion",
        description="MERLION Companion: language-guided online informative frame sampling for underwater vehicles.",
    )
    parser.add_argument("--version", action="version", version=f"merlion-companion {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    top = parser.add_subparsers(dest="command", metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}

    def add_command(name: str, help: str, group: str | None = None, group_help: str = "") -> argparse.ArgumentParser:
        where = top
        if group is not None:
            if group not in groups:
                gp = top.add_parser(group, help=group_help or f"{group} commands")
                gp.set_defaults(func=lambda args, _gp=gp: _gp.print_help() or 2)
                groups[group] = gp.add_subparsers(dest=f"{group}_command", metavar="COMMAND")
            where = groups[group]
        sub = where.add_parser(name, help=help, description=help)
        return sub

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(add_command)
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else logging.DEBUG if verbose >= 2 else logging.INFO
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    _setup_logging(args.verbose, args.quiet)
    try:
        code = args.func(args)
    except ConfigError as err:
        print(f"merlion: error: {err}", file=sys.stderr)
        return 2
    except MerlionError as err:
        print(f"merlion: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("merlion: interrupted", file=sys.stderr)
        return 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
