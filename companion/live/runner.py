"""What ``merlion run`` does, callable from tests and the demo: config -> companion -> run until told to stop."""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Mapping
from typing import Any

from companion.config import Config, load_config
from companion.live.companion import LiveCompanion, LiveOptions
from companion.live.notify import Notifier
from companion.sources.factory import check_file_source, check_source_uri
from vehicle.link.endpoint import parse_connection

log = logging.getLogger(__name__)


def cli_overrides(*, source: str | None = None, mavlink: str | None = None, store: str | None = None,
                  loop: bool = False) -> dict[str, Any]:
    """Command-line flags as config overrides (they win over the file and the environment)."""
    over: dict[str, Any] = {}
    if source is not None:
        over.setdefault("source", {})["uri"] = source
    if loop:
        over.setdefault("source", {})["loop"] = True
    if mavlink is not None:
        over.setdefault("mavlink", {})["connection"] = None if mavlink.lower() in ("none", "null", "") else mavlink
    if store is not None:
        over.setdefault("store", {})["dir"] = store
    return over


def build(config_path: str | None, overrides: dict[str, Any], environ: Mapping[str, str]) -> Config:
    """Everything validated before anything starts (a bad key: ConfigError, exit 2; a bad source URI or MAVLink
    connection string: exit 2), so that neither the store nor the encoder is touched for a typo."""
    cfg = load_config(config_path, overrides=overrides, environ=dict(environ))
    check_source_uri(cfg.source.uri)
    # a file or folder that cannot be read now never will be: said at start, not retried for the whole run
    check_file_source(cfg.source, "--source" if overrides.get("source", {}).get("uri") else "source.uri")
    if cfg.mavlink.connection:
        parse_connection(cfg.mavlink.connection)
    return cfg


def run_companion(cfg: Config, *, environ: Mapping[str, str], duration: float | None = None,
                  stop: threading.Event | None = None) -> dict[str, Any]:
    """Run until SIGTERM/SIGINT (when on the main thread), ``stop`` or ``duration``; returns the final report."""
    logging.getLogger().setLevel(cfg.log.level) if cfg.log.level != "INFO" else None
    stop = stop or threading.Event()
    companion = LiveCompanion(cfg, LiveOptions(notifier=Notifier.from_environ(environ)))
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, lambda signum, _frame: stop.set())
    try:
        companion.start()
        companion.run(duration=duration, stop=stop)
    finally:
        companion.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    report = companion.report()
    log.info("companion stopped: %s", companion.status_line())
    return report
