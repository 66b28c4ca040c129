"""Label-based evaluation: CSV formats, precision, coverage, the oracle summary, summary.json frames, AUROC."""

from __future__ import annotations

import json

import pytest

from companion.errors import MerlionError
from companion.evaluation.auroc import auroc, threshold_rates
from companion.evaluation.datasets import (
    LabelTable,
    load_dataset,
    load_humans,
    load_label_csv,
    read_summary_json,
)
from companion.evaluation.labels_eval import evaluate_labels, oracle_summary, positive_segments
from tests.conftest import shared_file
from vehicle.sim.dive_profile import load_profile


def _table() -> LabelTable:
    # frames 1-10: nothing; 11-20: fish; 21-25: nothing; 26-29: fish + crab; 30: crab only
    labels = {f: frozenset() for f in range(1, 31)}
    for f in range(11, 21):
        labels[f] = frozenset({"fish"})
    for f in range(26, 30):
        labels[f] = frozenset({"fish", "crab"})
    labels[30] = frozenset({"crab"})
    return LabelTable(labels=labels, source="hand", fps=10.0)


def test_segments_and_oracle_are_dealt_longest_first_and_centred():
    t = _table()
    assert positive_segments(t, "fish") == [list(range(11, 21)), [26, 27, 28, 29]]
    assert oracle_summary(t, 1, "fish") == [16]  # the longer segment gets the first pick, at its centre
    assert oracle_summary(t, 3, "fish") == [13, 18, 28]
    assert oracle_summary(t, 4, "fish") == [13, 18, 27, 29]


def test_precision_coverage_and_srum_against_the_oracle():
    t = _table()
    r = evaluate_labels(t, [5, 13, 18], "fish")
    assert r.precision == pytest.approx(2 / 3)
    assert r.coverage == pytest.approx(1 / 2)
    assert r.label_coverage == pytest.approx(1 / 2)  # fish seen, crab not
    assert r.oracle == [13, 18, 28]
    # 13 and 18 are matched exactly; 28 is 10 frames (1 s) from 18, inside tau = 2 s at 10 fps
    assert r.srum_oracle == pytest.approx(1.0)
    one = evaluate_labels(t, [1, 2, 16], "fish")  # frame 16 is within 2 s of every oracle frame
    assert one.srum_oracle == pytest.approx(1.0) and one.precision == pytest.approx(1 / 3)
    r2 = evaluate_labels(t, [30, 1], "fish")  # crab-only frame earns nothing for a fish query
    assert r2.precision == 0 and r2.coverage == 0 and r2.srum_oracle == 0
    with pytest.raises(MerlionError, match="query label 'shark'"):
        evaluate_labels(t, [5], "shark")
    with pytest.raises(MerlionError, match="frame 99"):
        evaluate_labels(t, [99], "fish")


def test_csv_formats(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("frame,labels\n1,\n2,Grey_fish_A;Reef_fish_A\n3,crab | fish\n")
    t = load_label_csv(a)
    assert t.labels == {1: frozenset(), 2: frozenset({"Grey_fish_A", "Reef_fish_A"}), 3: frozenset({"crab", "fish"})}
    b = tmp_path / "b.csv"
    b.write_text("frame_index,segment,fish_present\n0,0,0\n1,1,1\n2,1,1\n")
    t = load_label_csv(b, fps=10)
    assert t.labels == {1: frozenset(), 2: frozenset({"fish"}), 3: frozenset({"fish"})}
    assert t.segments == {1: "0", 2: "1", 3: "1"} and t.fps == 10
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,labels\n1,a\nx,b\n")
    with pytest.raises(MerlionError, match="line 3"):
        load_label_csv(bad)
    with pytest.raises(MerlionError, match="needs columns"):
        (tmp_path / "c.csv").write_text("foo,bar\n1,2\n")
        load_label_csv(tmp_path / "c.csv")
    wide = tmp_path / "wide.csv"
    wide.write_text("frame,labels\n1,fish\n2,crab,extra\n")  # an unquoted comma: more fields than the header
    with pytest.raises(MerlionError, match="line 3: 3 fields, the header names 2"):
        load_label_csv(wide)


@pytest.mark.parametrize(("rows", "message"), [
    ("0,1\n1,no\n", "line 3: fish_present 'no' is not 0 or 1"),  # was read as a fish
    ("0,1\n1,2\n", "line 3: fish_present '2' is not 0 or 1"),
    ("0,1\n1,maybe\n", "line 3: fish_present 'maybe' is not 0 or 1"),
    ("0,1\n-3,0\n", "line 3: frame_index -3 (0-based: must be 0 or more)"),  # was "frame -2"
    ("5,1\n5,0\n", "line 3: frame_index 5 appears twice"),  # was "frame 6"
])
def test_a_present_column_holds_0_or_1_and_errors_quote_the_frame_as_written(tmp_path, rows, message):
    f = tmp_path / "labels.csv"
    f.write_text("frame_index,fish_present\n" + rows)
    with pytest.raises(MerlionError) as info:
        load_label_csv(f)
    assert str(info.value) == f"{f}: {message}"


def test_survey_labels_give_two_fish_segments():
    t = load_label_csv(shared_file("survey/survey_480x270_labels.csv"), fps=10)
    assert t.num_frames == 93
    segs = positive_segments(t, "fish")
    assert [(s[0], s[-1]) for s in segs] == [(12, 41), (53, 82)]
    r = evaluate_labels(t, [2, 20, 30, 47, 60, 75], "fish")
    assert r.precision == pytest.approx(4 / 6) and r.coverage == 1.0


def test_summary_json_index_is_zero_based_source_frame(tmp_path):
    p = tmp_path / "summary.json"
    p.write_text(json.dumps({"frames": [{"index": 0, "time_s": 0.0}, {"index": 59, "time_s": 1.97}]}))
    assert read_summary_json(tmp_path)[0] == [1, 60]
    assert read_summary_json(p, label_fps=10)[0] == [1, 21]
    p.write_text(json.dumps({"frames": [{"time_s": 1}]}))
    with pytest.raises(MerlionError, match="index"):
        read_summary_json(p)


def test_binary_files_are_one_line_errors_not_tracebacks(tmp_path):
    """A JPEG passed where a text file belongs: each reader names the file (UnicodeDecodeError escaped before)."""
    jpeg = tmp_path / "photo.jpg"
    jpeg.write_bytes(b"\xff\xd8\xff\xe0 binary")
    data_set = tmp_path / "photo.json"
    data_set.write_bytes(jpeg.read_bytes())
    for read in (read_summary_json, load_humans, load_dataset, load_profile):
        path = data_set if read is load_dataset else jpeg
        with pytest.raises(MerlionError) as caught:
            read(path)
        assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value), read


def test_humans_file_formats(tmp_path):
    (tmp_path / "h.txt").write_text("# two people\n1 2 3\n4,5,6\n")
    assert load_humans(tmp_path / "h.txt") == {"h1": [1, 2, 3], "h2": [4, 5, 6]}
    (tmp_path / "h.json").write_text('{"ann": [7, 8]}')
    assert load_humans(tmp_path / "h.json") == {"ann": [7, 8]}


def test_auroc_hand_cases():
    assert auroc([0.9, 0.8, 0.2, 0.1], [1, 1, 0, 0]) == 1.0
    assert auroc([0.1, 0.2, 0.8, 0.9], [1, 1, 0, 0]) == 0.0
    # positives 0.9, 0.3; negatives 0.5, 0.1: pairs won 1 + 1 + 0 + 1 of 4
    assert auroc([0.9, 0.3, 0.5, 0.1], [1, 1, 0, 0]) == pytest.approx(0.75)
    assert auroc([1.0, 1.0, 1.0], [1, 0, 0]) == pytest.approx(0.5)  # all tied: chance
    with pytest.raises(MerlionError, match="both"):
        auroc([0.5, 0.6], [1, 1])
    rates = threshold_rates([0.9, 0.3, 0.5, 0.1], [1, 1, 0, 0], 0.4)
    assert rates == {"tau": 0.4, "recall": 0.5, "false_pass": 0.5, "precision": 0.5}
