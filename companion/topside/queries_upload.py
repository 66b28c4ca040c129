"""Send the topics to follow to the companion: /config/queries.txt over MAVLink FTP, then its answer.

The companion checks the file when the upload's session closes: it answers the closing request with an ACK and a
STATUSTEXT ``Queries set: ...`` (one topic) or ``Topics set: ...`` (several), or with a NAK, and
``Queries refused: why`` when the file itself is wrong. pymavlink's ``mavftp`` neither reports a NAK of the
closing request nor lets other messages through while it waits, so the upload is the surface tool's own
message-driven FTP client (``station_upload``), whose receive loop also hears the companion's status lines.
The file is checked with the vehicle's own parser before anything is sent.
"""

from __future__ import annotations

import logging
from pathlib import Path

from companion.config import MavlinkConfig
from companion.errors import UsageError
from companion.topside.station_upload import UploadAnswer, upload_file
from vehicle.camera.downlink import QUERIES_PATH
from vehicle.protocol.queries import MAX_BYTES, QueryTopic, format_queries, parse_queries

__all__ = ["QUERIES_PATH", "QueriesAnswer", "queries_from_file", "queries_from_options", "upload_queries"]

log = logging.getLogger("merlion.surface.queries")

CHECK_NAME = "main"
"""Stands for the vehicle's default topic name when a one-topic file is checked here (the vehicle names it)."""
ANSWERS = ("Queries set", "Topics set", "Queries refused")
"""The companion's STATUSTEXT answers to a queries upload."""


def queries_from_file(path: str | Path) -> bytes:
    """The file's bytes, checked as the vehicle will check them; UsageError names the file and what is wrong."""
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise UsageError(f"{path}: cannot read the queries file ({err.strerror})") from None
    try:
        parse_queries(data, CHECK_NAME)
    except ValueError as err:
        raise UsageError(f"{path}: {err}") from None
    return data


def queries_from_options(query: str | None, negatives: list[str], topics: list[dict]) -> bytes:
    """A queries file for ``--query``/``--negative`` (one topic: the vehicle's default) or ``--topic`` entries
    (``{"name", "positive", "negatives"}``, several topics, each under its own name)."""
    if query is not None and topics:
        raise UsageError("surface-queries: give --query (one topic) or --topic (several), not both")
    if query is not None:
        if not negatives:
            raise UsageError(f"--query {query!r}: give at least one --negative (the companion needs one)")
        text = format_queries([QueryTopic(CHECK_NAME, query, tuple(negatives))], CHECK_NAME)
        what = "--query"
    elif topics:
        if negatives:
            raise UsageError("--negative goes with --query; a --topic lists its negatives after ';'")
        listed = [QueryTopic(t["name"], t["positive"], tuple(t["negatives"])) for t in topics]
        text = format_queries(listed, "")  # "": no name is the default, so every topic keeps its [name] line
        what = "--topic"
    else:
        raise UsageError("surface-queries: give a FILE, --query TEXT --negative TEXT, or --topic NAME=POS;NEG")
    data = text.encode("utf-8")
    try:
        parse_queries(data, CHECK_NAME)
    except ValueError as err:
        raise UsageError(f"{what}: {err}") from None
    return data


QueriesAnswer = UploadAnswer
"""What the companion made of a queries upload (``status``: its ``Queries set``/``Topics set``/``Queries refused``)."""


def upload_queries(connect: str, cfg: MavlinkConfig, target: tuple[int, int], data: bytes, *,
                   timeout: float = 15.0) -> QueriesAnswer:
    """Upload ``data`` to ``/config/queries.txt`` of the companion ``target`` over a connection of our own and
    wait for its ACK or NAK and its status line. MerlionError when it never answered within ``timeout``."""
    if len(data) > MAX_BYTES:
        raise UsageError(f"the queries file is {len(data)} bytes, more than {MAX_BYTES}")
    answer = upload_file(connect, cfg, target, QUERIES_PATH, data, answers=ANSWERS, timeout=timeout,
                         name="surface-queries")
    log.info("queries upload to %d:%d: %s", target[0], target[1], answer.error or "accepted")
    return answer
