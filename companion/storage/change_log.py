"""The store's ``changes.jsonl``: one JSON object a line, appended whole or not at all.

A line can be torn two ways. A kill in the middle of a write leaves it without its newline: the next open cuts it
off (``end_torn_tail``). A full disk (or a file-size limit) takes the part of a line that fits in the file's last
block and refuses the rest: ``append`` cuts the file back to where the line began before it reports the failure
(shrinking a file needs no space), so the store goes memory-only with a log of whole lines, and the line it
appends when the disk takes writes again is not glued to half of an old one. Either way the next line read
stands alone.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

TAIL_BYTES = 65536
"""How far back from the end a torn line is looked for: a line is far shorter, the log itself may be long."""


class ChangeLog:
    """Appends and reads ``path``; only the store's one writer (``store_lock``) appends."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def append(self, entry: dict[str, Any]) -> None:
        """Add ``entry`` as one line and fsync it; OSError when refused, with the file as it was before."""
        line = memoryview((json.dumps(entry) + "\n").encode("utf-8"))
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            start = os.fstat(fd).st_size
            try:
                while line:
                    line = line[os.write(fd, line):]
                os.fsync(fd)
            except OSError:
                self._cut(fd, start)
                raise
        finally:
            os.close(fd)

    def _cut(self, fd: int, size: int) -> None:
        try:
            os.ftruncate(fd, size)
            os.fsync(fd)
        except OSError as err:  # a disk gone read-only: the next open cuts the torn line instead
            log.debug("%s: a torn line not cut back (%s)", self.path, err)

    def end_torn_tail(self) -> None:
        """Cut off a last line without its newline (a kill mid-write); OSError when the disk refuses."""
        try:
            with open(self.path, "rb+") as fh:
                size = fh.seek(0, os.SEEK_END)
                start = max(0, size - TAIL_BYTES)
                fh.seek(start)
                tail = fh.read()
                if tail and not tail.endswith(b"\n"):
                    cut = tail.rfind(b"\n")
                    fh.truncate(start + cut + 1 if cut >= 0 else start)
                    os.fsync(fh.fileno())
        except FileNotFoundError:
            return

    def last_summary(self) -> list[int]:
        """The summary the last whole entry recorded (rebuilding a lost summary.json); [] without one."""
        held: list[int] = []
        try:
            text = self.path.read_text(encoding="utf-8", errors="replace")
        except FileNotFoundError:
            return held
        for line in text.splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue  # a line cut short by a crash
            if isinstance(entry, dict) and isinstance(entry.get("summary"), list):
                try:
                    held = [int(i) for i in entry["summary"]]
                except (TypeError, ValueError):
                    continue  # a damaged entry: the one before it stands
        return held
