"""The gallery folder: thumbnails and tags written, mirrored, and read back after a restart."""

from __future__ import annotations

import csv
import json
import time

import pytest

from companion.errors import MerlionError
from companion.topside.gallery import LOG_COLUMNS, Capture, Gallery, Topic


def test_round_trip_add_thumbnail_remove_reopen(tmp_path):
    g = Gallery(tmp_path)
    assert g.announce(Capture(image_index=1, depth_m=3.5, heading_deg=45.0, time_utc=1.7e9))
    assert g.announce(Capture(image_index=2, depth_m=4.0))
    assert not g.announce(Capture(image_index=2, heading_deg=90.0))  # known: tags merged, not duplicated
    g.add_thumbnail(1, b"\xff\xd8one", via="push")
    g.add_thumbnail(2, b"\xff\xd8two", via="ftp")
    g.update_tags(2, score=0.75)
    assert (tmp_path / "summary" / "1.jpg").read_bytes() == b"\xff\xd8one"
    assert g.remove(1)
    assert not (tmp_path / "summary" / "1.jpg").exists()
    assert (tmp_path / "removed" / "1.jpg").read_bytes() == b"\xff\xd8one"

    again = Gallery(tmp_path)
    assert [c.image_index for c in again.summary()] == [2]
    two = again.get(2)
    assert (two.depth_m, two.heading_deg, two.score, two.thumbnail_via, two.thumbnail) == (
        4.0, 90.0, 0.75, "ftp", "summary/2.jpg")
    one = again.get(1)
    assert not one.in_summary and one.thumbnail == "removed/1.jpg"

    doc = json.loads((tmp_path / "gallery.json").read_text())
    assert doc["summary"] == [2]
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    assert [r["event"] for r in rows] == ["added", "added", "tags", "thumbnail", "thumbnail", "tags", "removed"]
    assert rows[-1]["image_index"] == "1" and rows[-1]["in_summary"] == "False"


def test_mirror_makes_the_summary_exactly_the_given_frames(tmp_path):
    g = Gallery(tmp_path)
    for i in (1, 2, 3):
        g.announce(Capture(image_index=i))
        g.add_thumbnail(i, bytes([i]))
    g.remove(2)
    assert g.mirror([2, 3, 4]) == [1]
    assert [c.image_index for c in g.summary()] == [4, 3, 2]  # newest first; 2 came back, 4 is new
    assert (tmp_path / "summary" / "2.jpg").exists() and (tmp_path / "removed" / "1.jpg").exists()
    assert g.missing_thumbnails() == [4]


def test_a_damaged_gallery_file_is_a_one_line_error(tmp_path):
    (tmp_path / "gallery.json").write_text("{not json")
    with pytest.raises(MerlionError, match="gallery.json"):
        Gallery(tmp_path)


def test_mirror_keeps_frames_announced_after_the_index_was_asked_for(tmp_path):
    g = Gallery(tmp_path)
    g.announce(Capture(image_index=1, announced_at=100.0))
    g.announce(Capture(image_index=2, announced_at=200.0))
    assert g.mirror([], announced_before=150.0) == [1]  # 2 is newer than the index: not yet in it, kept
    assert [c.image_index for c in g.summary()] == [2]


def test_a_stale_index_never_brings_back_a_frame_trimmed_after_it_was_asked_for(tmp_path):
    """The demo's 7-vs-6: index.json asked for, the trim STATUSTEXT arrives while the index is on its way (FTP
    is the lowest priority), then the index, built before the trim, still lists the frame."""
    g = Gallery(tmp_path)
    for i in (1, 2, 3):
        g.announce(Capture(image_index=i, announced_at=100.0))
    asked = time.time()
    assert g.remove(2)  # the trim arrives after the index was asked for
    assert g.mirror([1, 2, 3], announced_before=asked) == []
    assert [c.image_index for c in g.summary()] == [3, 1]
    g.remove(3)
    later = time.time() + 1  # an index asked for after both trims is the authority: 3 is held again
    g.mirror([1, 3], announced_before=later)
    assert [c.image_index for c in g.summary()] == [3, 1]


def test_a_capture_or_push_arriving_after_its_trim_goes_to_removed(tmp_path):
    g = Gallery(tmp_path)
    assert not g.remove(5)  # trimmed before we heard of it
    assert not g.announce(Capture(image_index=5, depth_m=3.0))  # the late capture: tags kept, not held
    g.add_thumbnail(5, b"\xff\xd8late\xff\xd9")
    five = Gallery(tmp_path).get(5)
    assert not five.in_summary and five.depth_m == 3.0 and five.thumbnail == "removed/5.jpg"
    assert (tmp_path / "removed" / "5.jpg").is_file() and not (tmp_path / "summary" / "5.jpg").exists()
    assert Gallery(tmp_path).summary() == []


def test_each_capture_keeps_its_topic_and_the_gallery_the_topics(tmp_path):
    g = Gallery(tmp_path)
    g.announce(Capture(image_index=1))
    g.add_thumbnail(1, b"\xff\xd8one")  # a push may come before anything says its topic
    assert g.get(1).topic is None
    assert g.update_tags(1, topic="fish")
    assert not g.announce(Capture(image_index=1, depth_m=3.0))  # a later announcement keeps the topic
    g.announce(Capture(image_index=2, topic="coral"))
    topics = [Topic("fish", "underwater image with fish", ("underwater image without fish",)),
              Topic("coral", "a coral reef", ("sand",))]
    assert g.set_topics(topics) and not g.set_topics(list(topics))

    again = Gallery(tmp_path)
    assert [(c.image_index, c.topic) for c in again.summary()] == [(2, "coral"), (1, "fish")]
    assert again.topics() == topics
    doc = json.loads((tmp_path / "gallery.json").read_text())
    assert doc["topics"][1] == {"name": "coral", "positive": "a coral reef", "negatives": ["sand"]}
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    assert [r["topic"] for r in rows if r["image_index"] == "1"] == ["", "", "fish", "fish"]


def test_a_gallery_folder_from_before_topics_still_opens_and_its_log_stays_aligned(tmp_path):
    old_columns = [c for c in LOG_COLUMNS if c != "topic"]
    (tmp_path / "summary").mkdir()
    (tmp_path / "summary" / "4.jpg").write_bytes(b"\xff\xd8four")
    (tmp_path / "gallery.json").write_text(json.dumps({
        "updated": 1.7e9, "dive": "5e1f0c2a", "dives": ["5e1f0c2a"], "summary": [4],
        "captures": [{"image_index": 4, "dive": "5e1f0c2a", "depth_m": 7.5, "score": 0.6, "thumbnail": "summary/4.jpg",
                      "thumbnail_via": "push", "in_summary": True}],
        "archived": []}))
    with (tmp_path / "log.csv").open("w", newline="") as fh:
        csv.writer(fh).writerow(old_columns)
        csv.writer(fh).writerow(["added", "1700000000.0", "5e1f0c2a", "4"] + [""] * (len(old_columns) - 4))

    g = Gallery(tmp_path)
    four = g.get(4)
    assert (four.topic, four.depth_m, four.thumbnail) == (None, 7.5, "summary/4.jpg")
    assert g.topics() == [] and g.dive == "5e1f0c2a"
    g.update_tags(4, topic="fish", score=0.7)
    g.set_topics([Topic("fish", "fish", ("no fish",))])
    with (tmp_path / "log.csv").open(newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == old_columns and all(len(r) == len(old_columns) for r in rows)  # no column slipped
    assert [r[0] for r in rows[1:]] == ["added", "tags", "topics"]
    assert Gallery(tmp_path).get(4).topic == "fish"


def test_a_gallery_file_whose_dive_is_a_path_is_a_one_line_error(tmp_path):
    (tmp_path / "gallery.json").write_text(json.dumps({"dive": "../../elsewhere", "captures": []}))
    with pytest.raises(MerlionError, match="gallery.json: .*not a safe name"):
        Gallery(tmp_path)


def test_deferred_writes_rewrite_gallery_json_once_per_interval_and_always_the_last_state(tmp_path):
    now = [100.0]
    g = Gallery(tmp_path, clock=lambda: now[0])
    g.defer_writes(0.25)
    for i in range(50):
        g.announce(Capture(image_index=i))
    g.wait_written()  # the writer thread owns the file
    assert g.json_writes == 1 and json.loads((tmp_path / "gallery.json").read_text())["summary"] == [0]
    assert len(list(csv.DictReader((tmp_path / "log.csv").open()))) == 50  # the history still has every event
    g.flush_due()
    assert g.json_writes == 1  # not yet: the interval has not passed
    now[0] += 0.25
    g.flush_due()
    g.wait_written()
    assert g.json_writes == 2 and len(Gallery(tmp_path).captures()) == 50
    g.remove(3)
    g.flush()  # the end of a run: the last state, at once
    g.flush()
    assert g.json_writes == 3 and Gallery(tmp_path).get(3).in_summary is False
