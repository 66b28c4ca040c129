"""Which setting a refused query came from, so the one-line error names it as it names a bad config value: the
option the user typed (``--query``) or the file and dotted key (``dive.yaml: queries.topics.1.positive``)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from companion.commands.overrides import OPTION_NAMES
from companion.errors import UsageError

if TYPE_CHECKING:
    from companion.config import Config, QueryConfig

# merlion imports every module here to build its parser: the configuration (pydantic, 0.15-0.25 s measured) and
# the query words are imported where they are used, by the commands that run


def query_keys(queries: QueryConfig) -> Iterator[tuple[tuple[str, ...], str]]:
    """Each query text of the configuration with its dotted key, positives first."""
    if queries.topics:
        for i, topic in enumerate(queries.topics):
            yield ("queries", "topics", str(i), "positive"), topic.positive
            for j, text in enumerate(topic.negatives):
                yield ("queries", "topics", str(i), "negatives", str(j)), text
        return
    yield ("queries", "positive"), queries.positive
    for j, text in enumerate(queries.negatives):
        yield ("queries", "negatives", str(j)), text


def query_source(cfg: Config, query: str, *, config: str | None, overrides: dict[str, Any] | None) -> str | None:
    """The option or ``FILE: key`` that set ``query``; None when the configuration does not hold it (a query
    uploaded from the surface before a restart, say)."""
    from companion.config import env_overrides, given_in

    for key, text in query_keys(cfg.queries):
        if text.strip().lower() != query.strip().lower():
            continue
        if overrides and given_in(overrides, key):
            return OPTION_NAMES.get(".".join(p for p in key[:3] if not p.isdigit()), "command line")
        env = env_overrides(dict(os.environ))
        if given_in(env, key):
            return f"environment {_variable(env, key)}"
        dotted = ".".join(key)
        return f"{config}: {dotted}" if config else dotted
    return None


def _variable(env: dict[str, Any], key: tuple[str, ...]) -> str:
    """The MERLION__ variable that set ``key``: its path down to the value it gave (a whole list, say)."""
    from companion.config import ENV_PREFIX

    node: Any = env
    parts: list[str] = []
    for part in key:
        if not isinstance(node, dict):
            break
        parts.append(part)
        node = node[part]
    return ENV_PREFIX + "__".join(p.upper() for p in parts)


@contextmanager
def blamed_queries(cfg: Config, *, config: str | None, overrides: dict[str, Any] | None) -> Iterator[None]:
    """A query word the encoder does not know is bad input (exit 2), named by where the query was set."""
    from companion.vision.encoders.query_words import UnknownWord

    try:
        yield
    except UnknownWord as err:
        where = query_source(cfg, err.query, config=config, overrides=overrides)
        raise UsageError(f"{where}: {err}" if where else str(err)) from None


def explained_config(args: argparse.Namespace, overrides: dict[str, Any]) -> Config:
    """The command's configuration; with ``--explain``, what each query was read as, on stderr, first."""
    from companion.config import load_config
    from companion.vision.query_explain import explain_queries  # WordNet only when asked

    cfg = load_config(args.config, overrides=overrides, options=OPTION_NAMES)
    if args.explain:
        with blamed_queries(cfg, config=args.config, overrides=overrides):
            print("\n".join(explain_queries(cfg)), file=sys.stderr, flush=True)
    return cfg

