"""merlion eval feedback: the first N + N labelled items become marks, the rest are scored with and without them."""

from __future__ import annotations

import json

import pytest

from companion.errors import MerlionError
from companion.evaluation.feedback_eval import read_item_labels, split_marks
from tests.conftest import run_merlion, shared_file


def test_first_n_of_each_class_become_marks_in_order():
    pos, neg, rest = split_marks([False, True, True, False, True, False], 2)
    assert pos == [1, 2] and neg == [0, 3] and rest == [4, 5]
    with pytest.raises(MerlionError, match="needs 3 positive and 3 negative"):
        split_marks([True, False, True, False], 3)


def test_label_csv_reads_the_present_column(tmp_path):
    f = tmp_path / "l.csv"
    f.write_text("image,fish_present,other\na.jpg,1,x\nb.jpg,0,y\n")
    assert read_item_labels(f) == {"a.jpg": True, "b.jpg": False}
    f.write_text("image,other\na.jpg,1\n")
    with pytest.raises(MerlionError, match="present"):
        read_item_labels(f)
    f.write_text("image,fish_present\na.jpg,1\nb.jpg,0\na.jpg,0\n")  # the last row used to overrule the first
    with pytest.raises(MerlionError, match=r"line 4: image 'a.jpg' is listed twice"):
        read_item_labels(f)
    f.write_text("image,fish_present\na.jpg,maybe\n")
    with pytest.raises(MerlionError, match=r"line 2: fish_present='maybe' is not a number"):
        read_item_labels(f)


def test_eval_feedback_on_suim():
    labels = shared_file("suim/labels.csv")
    images = labels.parent / "images"
    r = run_merlion("eval", "feedback", str(images), "--labels", str(labels), "--marks", "1",
                    "--encoder", "imagenet", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["marks"] == 1 and out["scored"] == 6 and out["positives"] == 3
    assert 0.5 <= out["auroc_query"] <= 1.0 and 0.5 <= out["auroc_marked"] <= 1.0
    too_many = run_merlion("eval", "feedback", str(images), "--labels", str(labels), "--marks", "5",
                           "--encoder", "imagenet")
    assert too_many.returncode == 1
    assert too_many.stderr.strip() == ("merlion: error: --marks 5: needs 5 positive and 5 negative items, "
                                       "have 4 and 4")


def test_eval_feedback_on_a_video_reads_frame_index_labels(tmp_path):
    import csv

    import cv2

    labels = shared_file("suim/labels.csv")
    rows = list(csv.DictReader(labels.open()))
    video = tmp_path / "dive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 5.0, (640, 480))
    for r in rows:
        writer.write(cv2.resize(cv2.imread(str(labels.parent / "images" / r["image"])), (640, 480)))
    writer.release()
    frame_labels = tmp_path / "dive.csv"
    frame_labels.write_text("frame_index,fish_present\n" + "".join(
        f"{i},{r['fish_present']}\n" for i, r in enumerate(rows)))
    r = run_merlion("eval", "feedback", str(video), "--labels", str(frame_labels), "--marks", "2",
                    "--encoder", "imagenet", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["scored"] == 4 and out["positives"] == 2
    short = tmp_path / "short.csv"
    short.write_text("frame_index,fish_present\n0,1\n")
    r = run_merlion("eval", "feedback", str(video), "--labels", str(short), "--marks", "1", "--encoder", "imagenet")
    assert r.returncode == 1 and r.stderr.strip() == f"merlion: error: --labels {short}: no label for frame index 1"
