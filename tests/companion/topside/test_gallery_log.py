"""log.csv on its own: its header, an older tool's header kept, and the row cap of a run."""

from __future__ import annotations

import csv

import pytest

from companion.errors import MerlionError
from companion.topside.capture import Capture
from companion.topside.gallery_log import LOG_COLUMNS, GalleryLog


def _rows(path):
    with path.open(newline="") as fh:
        return list(csv.reader(fh))


def test_a_new_log_gets_the_header_and_one_row_per_event(tmp_path):
    log = GalleryLog(tmp_path / "log.csv")
    log.append("added", Capture(image_index=3, dive="a1", depth_m=12.5, topic="fish"), "a1")
    rows = _rows(tmp_path / "log.csv")
    assert rows[0] == LOG_COLUMNS and len(rows) == 2
    row = dict(zip(LOG_COLUMNS, rows[1], strict=True))
    assert (row["event"], row["image_index"], row["depth_m"], row["topic"], row["lat"]) == ("added", "3", "12.5",
                                                                                           "fish", "")
    assert log.rows == 1 and log.rows_dropped == 0


def test_an_older_header_is_kept_so_rows_stay_aligned(tmp_path):
    old = [c for c in LOG_COLUMNS if c not in ("topic", "raw_score")]
    with (tmp_path / "log.csv").open("w", newline="") as fh:
        csv.writer(fh).writerow(old)
    GalleryLog(tmp_path / "log.csv").append("tags", Capture(image_index=1, topic="fish"), None)
    rows = _rows(tmp_path / "log.csv")
    assert rows[0] == old and len(rows[1]) == len(old) and "fish" not in rows[1]


def test_past_the_cap_one_log_full_row_then_none(tmp_path):
    log = GalleryLog(tmp_path / "log.csv", max_rows=3)
    for i in range(6):
        log.append("added", Capture(image_index=i), "a1")
    rows = _rows(tmp_path / "log.csv")
    assert [r[0] for r in rows[1:]] == ["added", "added", "added", "log_full"]
    assert rows[-1][LOG_COLUMNS.index("dive")] == "a1" and log.rows_dropped == 3


def test_a_log_that_is_not_text_is_a_one_line_error(tmp_path):
    (tmp_path / "log.csv").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(MerlionError, match="log.csv: not a log this tool can append to"):
        GalleryLog(tmp_path / "log.csv")


def test_text_off_the_link_never_makes_a_formula_cell(tmp_path):
    log = GalleryLog(tmp_path / "log.csv")
    cap = Capture(image_index=2, dive="-cmd", topic='=HYPERLINK("http://evil.example")', depth_m=-1.5,
                  file_url=' @SUM(1,2)')
    log.append("added", cap, "-cmd")
    row = dict(zip(LOG_COLUMNS, _rows(tmp_path / "log.csv")[1], strict=True))
    assert (row["dive"], row["topic"], row["file_url"]) == ("'-cmd", '\'=HYPERLINK("http://evil.example")',
                                                            "' @SUM(1,2)")
    assert row["depth_m"] == "-1.5" and row["image_index"] == "2"  # numbers stay numbers
