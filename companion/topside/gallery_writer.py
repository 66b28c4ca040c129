"""The one owner of gallery.json: replaces it atomically with the latest state handed to it, on its own thread.

The receive loop hands over a ``GalleryText`` (cheap: its pieces are already text) and goes on; the writer joins
it and writes it (temp file, fsync, rename, as ``atomic_write`` does). States handed over while a write is under way
replace each other: the latest wins, and none is written twice. A kill -9 loses what changed since the last state
handed over (at most the gallery's write interval) and the one being written, never the previous file. The
thread starts with the first state and ends after ``IDLE_S`` with nothing to write; ``wait`` blocks until the
latest state is on disk (the end of a run).
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.topside.gallery_json import GalleryText

log = logging.getLogger("merlion.surface")

IDLE_S = 5.0
"""The writer thread ends after this long with nothing to write (the next state starts it again)."""


class GalleryWriter:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._cond = threading.Condition()
        self._pending: GalleryText | None = None
        self._handed = 0
        """States handed over."""
        self._done = 0
        """The number of the last state written (or given up on an error)."""
        self._error: OSError | None = None
        self._thread: threading.Thread | None = None
        self._logged = ""
        self.writes = 0
        """Files written (states replaced while waiting are not)."""

    def write_now(self, text: GalleryText) -> None:
        """Write ``text`` on the caller's thread (a gallery writing through); an OSError is the caller's."""
        with self._cond:
            while self._pending is not None or self._done < self._handed:
                self._cond.wait()  # the thread's write first: the latest state stays the last written
            atomic_write(self.path, text.render())
            self.writes += 1

    def hand_over(self, text: GalleryText) -> None:
        """Queue ``text`` for the writer thread, replacing any state still waiting."""
        with self._cond:
            self._pending = text
            self._handed += 1
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="gallery.json writer", daemon=True)
                self._thread.start()
            self._cond.notify_all()

    def wait(self, timeout: float | None = None) -> None:
        """Until every state handed over is on disk; the last write's OSError, if it failed, is raised here."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._done >= self._handed, timeout):
                raise TimeoutError(f"{self.path}: not written within {timeout} s")
            error, self._error = self._error, None
        if error is not None:
            raise error

    def _run(self) -> None:
        while True:
            with self._cond:
                if not self._cond.wait_for(lambda: self._pending is not None, IDLE_S):
                    self._thread = None
                    return
                text, number, self._pending = self._pending, self._handed, None
            error = None
            try:
                atomic_write(self.path, text.render())
            except OSError as err:
                error = err
                if str(err) != self._logged:  # a full disk is one line, not four a second
                    log.warning("%s: cannot write it (%s); the next change tries again", self.path,
                                err.strerror or err)
            self._logged = "" if error is None else str(error)
            with self._cond:
                self._done = number
                self._error = error
                self.writes += error is None
                self._cond.notify_all()
