"""``merlion score`` end to end: real images, the packaged encoder, a real subprocess."""

from __future__ import annotations

import csv
import json
import shutil

import pytest

from companion.config import load_config
from companion.errors import MerlionError
from companion.vision.score_images import score_images
from tests.conftest import run_merlion, shared_file


def test_json_lines_for_a_folder_rank_fish_above_no_fish():
    folder = shared_file("suim/images")
    fish = {r["image"]: int(r["fish_present"]) for r in csv.DictReader(shared_file("suim/labels.csv").open())}
    proc = run_merlion("score", str(folder), "--encoder", "imagenet", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    assert sorted(r["file"].rsplit("/", 1)[-1] for r in rows) == sorted(fish)
    assert [r["file"] for r in rows].index(str(folder / "f_r_329_.jpg")) < \
        [r["file"] for r in rows].index(str(folder / "f_r_1965_.jpg"))  # natural order: 329 before 1965
    assert all(0 < r["score"] < 1 for r in rows)
    by_label = {0: [], 1: []}
    for r in rows:
        by_label[fish[r["file"].rsplit("/", 1)[-1]]].append(r["score"])
    assert sum(by_label[1]) / 4 > sum(by_label[0]) / 4


def test_text_lines_and_an_undecodable_file(tmp_path):
    good = tmp_path / "good.jpg"
    shutil.copyfile(shared_file("suim/images/n_l_100_.jpg"), good)  # a copy in tmp, never in the repo
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8 not really a jpeg")
    proc = run_merlion("score", str(good), str(bad), "--encoder", "imagenet", "--query", "sharks or fish")
    assert proc.returncode == 1
    path, score = proc.stdout.strip().split("\t")
    assert path == str(good) and 0 < float(score) < 1
    assert proc.stderr.strip().splitlines()[-1] == f"merlion: error: {bad}: cannot decode as an image"


def test_missing_path_and_unknown_concept_are_one_line_errors(tmp_path):
    proc = run_merlion("score", str(tmp_path / "nope.jpg"), "--encoder", "imagenet")
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"merlion: error: {tmp_path / 'nope.jpg'}: no such file or folder"
    cfg = load_config(overrides={"encoder": {"name": "imagenet"}, "queries": {"positive": "a red blorptang"}})
    with pytest.raises(MerlionError, match=r"'blorptang' is not an English word .* near words: "):
        list(score_images(cfg, [shared_file("suim/images/n_l_100_.jpg")]))


def test_explain_says_what_each_query_was_read_as():
    """`--explain` prints, before the scores, each query's WordNet reading: "reef fish" is a fish on reefs,
    not the class "coral reef", which the negative names."""
    proc = run_merlion("score", str(shared_file("suim/images/n_l_100_.jpg")), "--encoder", "imagenet",
                       "--query", "reef fish", "--negative", "coral reef", "--explain", "--json")
    assert proc.returncode == 0, proc.stderr
    assert ("positive query 'reef fish':\n  reef fish -> fish [narrowed by reef]: 1 classes: anemone fish\n"
            "negative query 'coral reef':\n  coral reef -> coral reef [noun]: 1 classes: coral reef") in proc.stderr
    assert 0 < json.loads(proc.stdout)["score"] < 1  # stdout stays JSON lines
