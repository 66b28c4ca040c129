"""log.csv: one appended row per gallery event (added, thumbnail, tags, removed, dive, topics), for spreadsheets and
audits; at most ``MAX_LOG_ROWS`` rows a run; no cell a spreadsheet can run (``sheet_safe``: the text comes off the
link). A log started by an older tool keeps its own header, so rows never slip a column."""

from __future__ import annotations

import csv
import logging
import time
from pathlib import Path

from companion.errors import MerlionError
from companion.export.viame_csv import sheet_safe
from companion.topside.capture import Capture

log = logging.getLogger("merlion.surface")

MAX_LOG_ROWS = 100_000
"""Rows appended to log.csv per run (about 100 bytes each): a day's diving writes a few thousand."""

LOG_COLUMNS = [
    "event", "wall_time", "dive", "image_index", "in_summary", "time_utc", "depth_m", "heading_deg", "score",
    "lat", "lon", "alt_m", "thumbnail", "thumbnail_via", "file_url", "topic", "raw_score",
]


class GalleryLog:
    """Appends the rows; the gallery calls it under its own lock."""

    def __init__(self, path: Path, max_rows: int = MAX_LOG_ROWS) -> None:
        self.path = path
        self.max_rows = max_rows
        self.rows = 0
        """Rows appended to log.csv by this run."""
        self.rows_dropped = 0
        """Events of this run past ``max_rows``: not in log.csv (gallery.json still has the state)."""
        self._columns = self._existing_columns()

    def _existing_columns(self) -> list[str]:
        """The columns log.csv already has (a folder from an older tool keeps its header: rows stay aligned)."""
        try:
            with self.path.open(newline="", encoding="utf-8") as fh:
                header = next(csv.reader(fh), None)
        except FileNotFoundError:
            return list(LOG_COLUMNS)
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise MerlionError(f"{self.path}: not a log this tool can append to ({err})") from None
        return header if header and set(header) <= set(LOG_COLUMNS) else list(LOG_COLUMNS)

    def append(self, event: str, cap: Capture, dive: str | None) -> None:
        """One row for ``event`` on ``cap``. Past ``max_rows`` rows this run, one ``log_full`` row (of ``dive``) and
        then none (each event of a sender announcing without end was a row, the file growing for the whole run)."""
        if self.rows > self.max_rows:
            self.rows_dropped += 1
            return
        if self.rows == self.max_rows:
            log.warning("%s: %d rows this run: no more are written (log_rows_dropped; gallery.json keeps the "
                        "state)", self.path, self.max_rows)
            self.rows_dropped += 1
            event, cap = "log_full", Capture(image_index=-1, dive=dive)
        self.rows += 1
        new = not self.path.exists()
        if new:
            self._columns = list(LOG_COLUMNS)
        with self.path.open("a", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            if new:
                writer.writerow(self._columns)
            row = cap.to_dict()
            row.update(event=event, wall_time=f"{time.time():.3f}")
            # the dive, topic and file_url come off the link: no cell of them may run as a spreadsheet formula
            writer.writerow(["" if row.get(k) is None else sheet_safe(str(row.get(k))) for k in self._columns])
