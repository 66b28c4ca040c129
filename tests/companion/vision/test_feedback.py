"""Marked examples combined with the query score (companion.vision.feedback), on features and on real images."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.feedback import GAIN, ExampleScorer, MarkedPreSampler, Marks, mark_weight
from companion.vision.presampler import PreSampler
from tests.conftest import run_merlion, shared_file


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + np.exp(-x))


def test_example_score_is_half_way_at_the_mid_point_and_high_at_the_like_prototype():
    like = np.array([[1.0, 0.0, 0.0]])
    unlike = np.array([[0.0, 1.0, 0.0]])
    scorer = ExampleScorer(Marks.from_features(like, unlike))
    s = scorer.scores(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    assert s[0] == pytest.approx(_sigmoid(GAIN))
    assert s[1] == pytest.approx(_sigmoid(-GAIN))
    assert s[2] == pytest.approx(0.5)


def test_one_sided_marks_compare_with_the_running_mean_of_the_frames_seen():
    scorer = ExampleScorer(Marks.from_features(np.array([[1.0, 0.0]]), np.zeros((0, 2))))
    frames = np.array([[1.0, 0.1], [0.0, 1.0], [0.1, 1.0]])
    assert np.allclose(scorer.scores(frames), 0.5)  # nothing seen yet: no second prototype
    scorer.observe(frames)
    s = scorer.scores(frames)
    assert s[0] > 0.8 and s[1] < 0.5 and s[2] < 0.5


def test_mark_weight_grows_with_the_number_of_marks():
    assert mark_weight(0) == 0.0
    assert mark_weight(2) == 0.5
    assert mark_weight(10) == pytest.approx(10 / 12)


@pytest.fixture(scope="module")
def suim():
    import cv2

    labels = shared_file("suim/labels.csv")
    rows = list(csv.DictReader(labels.open()))
    paths = [labels.parent / "images" / r["image"] for r in rows]
    return paths, [cv2.imread(str(p)) for p in paths], np.array([r["fish_present"] == "1" for r in rows])


def test_marks_pull_the_combined_score_towards_the_marked_images(suim):
    _, images, fish = suim
    encoder = ImageNetEncoder(EncoderConfig(name="imagenet"))
    base = PreSampler(encoder, "fish", ["no fish"])
    emb = encoder.encode_images(images)
    query = base.scores(emb)
    first_fish, first_empty = int(np.flatnonzero(fish)[0]), int(np.flatnonzero(~fish)[0])
    # mark them the "wrong" way round: the combined score must follow the marks, not the query
    marked = MarkedPreSampler(base, Marks.from_images(encoder, [images[first_empty]], [images[first_fish]]))
    combined = marked.scores(emb)
    assert marked.weight == 0.5 and marked.tau_ss == base.tau_ss and marked.queries == base.queries
    assert combined[first_empty] - query[first_empty] > 0.1
    assert combined[first_fish] < query[first_fish]
    assert combined[first_empty] > combined[first_fish] + 0.3
    assert np.all((combined > 0) & (combined < 1))


def test_score_command_takes_like_and_unlike(suim, tmp_path):
    paths, _, fish = suim
    empty = str(paths[int(np.flatnonzero(~fish)[0])])
    target = str(paths[int(np.flatnonzero(fish)[0])])
    plain = run_merlion("score", empty, "--encoder", "imagenet", "--json")
    marked = run_merlion("score", empty, "--encoder", "imagenet", "--json", "--like", empty, "--unlike", target)
    assert plain.returncode == 0 and marked.returncode == 0, plain.stderr + marked.stderr
    assert json.loads(marked.stdout)["score"] > json.loads(plain.stdout)["score"] + 0.1
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not an image")
    out = run_merlion("score", empty, "--encoder", "imagenet", "--like", str(bad))
    assert out.returncode != 0
    assert out.stderr.strip().splitlines()[-1] == f"merlion: error: --like {bad}: cannot decode as an image"


def test_summarize_keeps_frames_by_the_combined_score(tmp_path):
    """Marks that agree with each other and contradict the query win: the summary follows the marks."""
    import cv2

    video = shared_file("survey/survey_480x270.mp4")
    rows = list(csv.DictReader(shared_file("survey/survey_480x270_labels.csv").open()))
    fish = [r["fish_present"] == "1" for r in rows]
    cap = cv2.VideoCapture(str(video))
    frames = [cap.read()[1] for _ in range(len(fish))]
    cap.release()
    first = {}  # first frame of each segment
    for i, r in enumerate(rows):
        first.setdefault(int(r["segment"]), i)
    marks = {}  # two frames from each of the first two segments: marks of a kind that look alike
    for seg, step, option in ((0, 0, "--like"), (0, 3, "--like"), (1, 0, "--unlike"), (1, 3, "--unlike")):
        path = tmp_path / f"seg{seg}_{step}.png"
        cv2.imwrite(str(path), frames[first[seg] + step])
        marks.setdefault(option, []).append(str(path))
    args = [a for option, paths in marks.items() for p in paths for a in (option, p)]
    r = run_merlion("summarize", str(video), "--out", str(tmp_path / "s"), "--encoder", "imagenet", "-k", "4", *args)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert doc["params"]["marks"] == {"like": marks["--like"], "unlike": marks["--unlike"]}
    kept = [fish[f["index"]] for f in doc["frames"]]
    assert kept and sum(kept) < len(kept) / 2  # mostly no-fish frames, although the query asks for fish


def test_marks_that_contradict_each_other_are_not_trusted():
    like = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    unlike = np.array([[0.0, 1.0, 0.05], [1.0, 0.0, 0.05]])  # each unlike mark sits on a like mark
    marks = Marks.from_features(like, unlike, np.array([0.6, 0.6]), np.array([0.4, 0.4]))
    assert marks.agreement() == 0.0 and marks.trust() == 0.0


def test_marks_are_trusted_only_where_they_rank_the_marked_frames_better_than_the_query():
    like = np.array([[1.0, 0.1, 0.0], [1.0, 0.0, 0.1], [0.9, 0.0, 0.0]])
    unlike = np.array([[0.0, 1.0, 0.1], [0.1, 1.0, 0.0], [0.0, 0.9, 0.0]])
    assert Marks.from_features(like, unlike).agreement() == 1.0
    # the query already ranks the marks right: the marks add nothing and weigh nothing
    agrees = Marks.from_features(like, unlike, np.array([0.9, 0.8, 0.7]), np.array([0.3, 0.2, 0.1]))
    assert agrees.trust() == 0.0
    # the query ranks them backwards (raw cyan footage): the marks correct it and are trusted
    backwards = Marks.from_features(like, unlike, np.array([0.2, 0.3, 0.1]), np.array([0.7, 0.8, 0.9]))
    assert backwards.trust() > 0.0
    base = PreSampler(ImageNetEncoder(EncoderConfig(name="imagenet")), "fish")
    assert MarkedPreSampler(base, agrees).weight == 0.0
    assert MarkedPreSampler(base, backwards).weight == pytest.approx(backwards.trust() * mark_weight(6))
