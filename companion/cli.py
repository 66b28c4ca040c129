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
import re
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

from companion import __version__, commands
from companion.errors import MerlionError

log = logging.getLogger("merlion")

AddCommand = Callable[..., argparse.ArgumentParser]


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a bad argument is the one line every other bad input gets (``merlion: error: summarize -k:
    invalid int value: 'abc' (see merlion summarize --help)``), exit 2, not the whole usage above it; the
    subcommands' parsers are of this class too (argparse makes them with the parent's class)."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix("merlion").strip()
        what, why = message, ""
        if match := re.match(r"argument (\S+): (.*)$", message, re.S):
            what, why = match.groups()
        elif match := re.match(r"the following arguments are required: (.*)$", message, re.S):
            what, why = match.group(1), "required"
        elif match := re.match(r"unrecognized arguments: (.*)$", message, re.S):
            what, why = match.group(1), "unknown option or extra argument"
        line = " ".join(p for p in (command, what) if p) + (f": {why}" if why else "")
        hint = f"merlion {command} --help" if command else "merlion --help"
        self.exit(2, f"merlion: error: {line} (see {hint})\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
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
        sub.set_defaults(parser=sub)  # an option no parser knew is blamed on this subcommand, not on merlion
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
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        getattr(args, "parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    _setup_logging(args.verbose, args.quiet)
    # the configuration (pydantic): 0.15-0.25 s measured, after parsing, so `merlion --help` does not pay it
    from companion.config import ConfigError

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
