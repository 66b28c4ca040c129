"""Progress of a long offline run: tqdm's bar on a terminal, plain lines at a modest rate elsewhere.

A bar redrawn in place is noise in a log file or a CI job, so tqdm is off when stderr is not a terminal; but a
silent 86-s ``summarize`` of a 22-s clip looks hung. Off a terminal, a line says how far the run is when the
first batch is done (the model loaded, frames flowing) and then every ``every_s`` seconds, so a short run prints
one line and an hour-long one a few hundred.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

from tqdm import tqdm

EVERY_S = 10.0
"""Seconds between two plain progress lines."""


class ProgressLines:
    """The part of tqdm's interface the runs use (``update``, ``set_postfix``, a context manager), as plain lines:
    ``summarize: 120/660 frames (18%), passed 12, held 6``."""

    def __init__(self, what: str, unit: str, total: int | None, *, every_s: float = EVERY_S,
                 stream: TextIO | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.what = what
        self.unit = unit
        self.total = total
        self.every_s = every_s
        self.stream = stream if stream is not None else sys.stderr
        self.clock = clock
        self.done = 0
        self.postfix: dict[str, object] = {}
        self._last: float | None = None

    def set_postfix(self, **values: object) -> None:
        """Figures said after the count on the next line (tqdm redraws at once; a line waits for its turn)."""
        self.postfix = values

    def update(self, n: int = 1) -> None:
        self.done += n
        now = self.clock()
        if self._last is None or now - self._last >= self.every_s:
            self._last = now
            print(self.line(), file=self.stream, flush=True)

    def line(self) -> str:
        unit = self.unit if self.done == 1 and not self.total else f"{self.unit}s"
        count = f"{self.done} {unit}"
        if self.total:
            count = f"{self.done}/{self.total} {unit} ({min(100, round(100 * self.done / self.total))}%)"
        extra = "".join(f", {key} {value}" for key, value in self.postfix.items())
        return f"{self.what}: {count}{extra}"

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def progress(what: str, unit: str, total: int | None, enabled: bool | None) -> tqdm | ProgressLines:
    """``enabled`` None: a bar on a terminal, plain lines elsewhere; True: the bar; False: nothing."""
    if enabled is None and not sys.stderr.isatty():
        return ProgressLines(what, unit, total)
    return tqdm(total=total, unit=unit, desc=what, disable=enabled is False, file=sys.stderr)
