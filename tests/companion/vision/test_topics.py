"""Several topics at once on the survey video: one encoder pass per frame, a summary of K frames per topic.

A topic's summary must not depend on the other topics followed beside it, so each topic's summary in a two-topic
run is compared with a run that follows that topic alone.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.config import Config, EncoderConfig, build_config
from companion.errors import UsageError
from companion.sources.video import VideoSource
from companion.vision.encoders.counted import CountedEncoder
from companion.vision.encoders.imagenet import ImageNetEncoder
from companion.vision.pipeline import Pipeline
from companion.vision.topics import TopicSpec
from tests.companion.vision.helpers import run
from tests.conftest import run_merlion, shared_file

FISH = {"name": "fish", "positive": "underwater image with fish", "negatives": ["underwater image without fish"]}
CORAL = {"name": "coral", "positive": "underwater image of a coral reef", "negatives": []}


@pytest.fixture(scope="module")
def encoder():
    return ImageNetEncoder(EncoderConfig(name="imagenet", batch=8), regions=False)


@pytest.fixture(scope="module")
def frames():
    return list(VideoSource(shared_file("survey/survey_480x270.mp4"), fps=4))


def make(encoder, topics, k=3, tau=0.3, first=0):
    cfg = Config.model_validate({"sampler": {"k": k}, "queries": {"tau_ss": tau, "topics": topics},
                                 "gate": {"mode": "none"}})
    return Pipeline.from_config(cfg, encoder, first_image_index=first)


def held_frames(pipe, name):
    return [f.frame_index for f in pipe.topic(name).summary]


@pytest.fixture(scope="module")
def two_topics(encoder, frames):
    counting = CountedEncoder(encoder)
    pipe = make(counting, [FISH, CORAL])
    results, events = run(pipe, frames)
    return pipe, results, events, counting


def test_one_encoder_pass_serves_every_topic(two_topics, frames):
    pipe, results, _, counting = two_topics
    assert counting.images == len(frames)  # not one per topic
    assert counting.calls == -(-len(frames) // 8)
    assert all(set(r.topic_scores) == {"fish", "coral"} for r in results)
    assert all(r.score == max(r.topic_scores.values()) for r in results)
    assert all(r.passed == any(s > 0.3 for s in r.topic_scores.values()) for r in results)


def test_each_topic_keeps_its_own_summary_of_k(two_topics, encoder, frames):
    pipe, results, events, _ = two_topics
    fish, coral = held_frames(pipe, "fish"), held_frames(pipe, "coral")
    assert 1 <= len(fish) <= 3 and 1 <= len(coral) <= 3
    assert {f.topic for f in pipe.topic("fish").summary} == {"fish"}
    assert {f.topic for f in pipe.topic("coral").summary} == {"coral"}
    # every frame held passed its own topic's threshold, whatever the other topic said
    by_frame = {r.frame_index: r for r in results}
    for name in ("fish", "coral"):
        for frame in pipe.topic(name).summary:
            assert by_frame[frame.frame_index].topic_scores[name] > 0.3
            assert frame.score == pytest.approx(by_frame[frame.frame_index].topic_scores[name], abs=1e-6)
    # the same summary as following that topic alone
    for topic in (FISH, CORAL):
        alone = make(encoder, [topic])
        run(alone, frames)
        assert held_frames(alone, topic["name"]) == held_frames(pipe, topic["name"])
    # image indices are unique across topics, and the events replay to the union of both summaries
    keys = [f.image_index for f in pipe.summary]
    assert len(keys) == len(set(keys))
    replay: set[int] = set()
    for event in events:
        (replay.add if event.kind == "added" else replay.discard)(event.frame.image_index)
        assert set(event.summary) <= {e.frame.image_index for e in events if e.kind == "added"}
    assert replay == set(keys) and events[-1].summary == keys


def test_k_and_tau_change_every_topic(encoder, frames):
    pipe = make(encoder, [FISH, CORAL], k=4, tau=0.2)
    run(pipe, frames)
    before = {t.name: len(t.summary) for t in pipe.topics}
    removed = pipe.set_k(1)
    assert {t.name: len(t.summary) for t in pipe.topics} == {n: min(1, c) for n, c in before.items()}
    assert len(removed) == sum(before.values()) - sum(min(1, c) for c in before.values())
    pipe.tau_ss = 0.9
    assert [t.presampler.tau_ss for t in pipe.topics] == [0.9, 0.9]


def test_set_topics_keeps_renews_and_drops(two_topics, encoder, frames):
    pipe = make(encoder, [FISH, CORAL])
    run(pipe, frames[:16])
    fish_before = held_frames(pipe, "fish")
    coral_keys = [f.image_index for f in pipe.topic("coral").summary]
    events = pipe.set_topics([TopicSpec("fish", "underwater image with a fish", ("underwater image without fish",)),
                              TopicSpec("debris", "underwater image of a wreck")])
    assert [t.name for t in pipe.topics] == ["fish", "debris"]
    assert held_frames(pipe, "fish") == fish_before  # a kept topic keeps its summary; its queries changed
    assert pipe.topic("fish").presampler.positive == "underwater image with a fish"
    assert pipe.topic("debris").summary == []
    assert sorted(e.frame.image_index for e in events) == sorted(coral_keys)
    assert all(e.kind == "removed" for e in events)
    run(pipe, frames[16:])
    assert all(f.topic in ("fish", "debris") for f in pipe.summary)
    with pytest.raises(UsageError, match="used twice"):
        pipe.set_topics([TopicSpec("a", "x"), TopicSpec("a", "y")])


def test_restore_puts_frames_back_in_their_topics(two_topics, encoder):
    source = two_topics[0]
    fish = source.topic("fish").summary
    coral = source.topic("coral").summary
    untagged = type(fish[0])(**{**fish[0].__dict__, "topic": ""})  # stored before topics existed
    pipe = make(encoder, [FISH, {"name": "wreck", "positive": "underwater image of a wreck"}])
    removed = pipe.restore([untagged, *fish[1:], *coral])
    assert [f.image_index for f in pipe.topic("fish").summary] == [f.image_index for f in fish]
    assert pipe.topic("fish").summary[0].topic == "fish"  # an untagged frame belongs to the default topic
    assert pipe.topic("wreck").summary == []
    # a topic no longer followed: its frames leave, and the store hears so
    assert sorted(e.frame.image_index for e in removed) == sorted(f.image_index for f in coral)
    assert all(e.kind == "removed" for e in removed)
    assert pipe.next_image_index == max(f.image_index for f in [*fish, *coral]) + 1


def test_config_refuses_bad_topics():
    with pytest.raises(Exception, match="used twice"):
        build_config({"queries": {"topics": [FISH, FISH]}})
    with pytest.raises(Exception, match="queries.topics.0.name"):
        build_config({"queries": {"topics": [{**FISH, "name": "Fish and more"}]}})
    assert [t.name for t in build_config({}).queries.topic_list()] == ["main"]


def test_summarize_command_writes_a_summary_per_topic(tmp_path):
    video = shared_file("survey/survey_480x270.mp4")
    out = tmp_path / "two"
    proc = run_merlion("summarize", str(video), "--out", str(out), "--encoder", "imagenet", "-k", "3",
                       "--topic", "fish=underwater image with fish;underwater image without fish",
                       "--topic", "coral=underwater image of a coral reef")
    assert proc.returncode == 0, proc.stderr
    assert "contact_sheet_fish.jpg, contact_sheet_coral.jpg" in proc.stdout
    doc = json.loads((out / "summary.json").read_text())
    topics = {t["name"]: t for t in doc["params"]["topics"]}
    assert set(topics) == {"fish", "coral"}
    stats = doc["params"]["stats"]
    assert stats["encoder_images"] == stats["frames_encoded"]  # one encoder pass per frame for both topics
    for name, topic in topics.items():
        mine = [f for f in doc["frames"] if f["topic"] == name]
        assert len(mine) == topic["frames"] and 1 <= len(mine) <= 3
        assert all(f["file"].startswith(f"frames/{name}/") and (out / f["file"]).is_file() for f in mine)
        assert (out / topic["contact_sheet"]).is_file()
    assert np.all(np.diff([f["time_s"] for f in doc["frames"]]) >= 0)

    bad = run_merlion("summarize", str(video), "--out", str(tmp_path / "bad"), "--topic", "fish")
    assert bad.returncode == 2 and "--topic: 'fish': expected NAME=POSITIVE" in bad.stderr.strip().splitlines()[-1]
    named = run_merlion("summarize", str(video), "--out", str(tmp_path / "bad"), "--topic", "Big Fish=fish")
    assert named.returncode != 0
    assert named.stderr.strip().splitlines() == [named.stderr.strip()]
    assert "queries.topics.0.name" in named.stderr and "Big Fish" in named.stderr
    assert not (tmp_path / "bad").exists()


def test_score_command_gives_each_topic_from_one_pass(tmp_path):
    images = shared_file("suim/images")
    files = sorted(images.iterdir())[:4]
    single = run_merlion("score", *map(str, files), "--encoder", "imagenet", "--json")
    both = run_merlion("score", *map(str, files), "--encoder", "imagenet", "--json",
                       "--topic", "fish=underwater image with fish;underwater image without fish",
                       "--topic", "coral=underwater image of a coral reef")
    assert single.returncode == 0 and both.returncode == 0, both.stderr
    alone = [json.loads(line) for line in single.stdout.splitlines()]
    rows = [json.loads(line) for line in both.stdout.splitlines()]
    assert [r["file"] for r in rows] == [str(f) for f in files]
    for one, row in zip(alone, rows, strict=True):
        assert set(row["topics"]) == {"fish", "coral"}
        assert row["topics"]["fish"] == pytest.approx(one["score"], abs=1e-6)  # the default query is fish's
        assert row["score"] == pytest.approx(max(row["topics"].values()), abs=1e-6)


def test_a_topic_added_live_takes_the_shared_threshold_as_after_a_restart(encoder):
    """A topic without its own tau_ss gets queries.tau_ss (then MERL_TAU_SS), never the first topic's own."""
    pipe = make(encoder, [{**FISH, "tau_ss": 0.9}, CORAL], tau=0.4)
    assert [t.presampler.tau_ss for t in pipe.topics] == [0.9, 0.4]
    pipe.set_topics([TopicSpec("fish", FISH["positive"], tuple(FISH["negatives"])),
                     TopicSpec("wreck", "underwater image of a wreck")])
    assert pipe.topic("fish").presampler.tau_ss == 0.9 and pipe.topic("wreck").presampler.tau_ss == 0.4
    restarted = make(encoder, [{**FISH, "tau_ss": 0.9}, {"name": "wreck", "positive": "underwater image of a wreck"}],
                     tau=0.4)
    assert restarted.topic("wreck").presampler.tau_ss == pipe.topic("wreck").presampler.tau_ss
    pipe.tau_ss = 30  # MERL_TAU_SS, as a percentage: every topic, and the next one added
    pipe.set_topics([*(TopicSpec(t.name, t.presampler.positive, tuple(t.presampler.negatives)) for t in pipe.topics),
                     TopicSpec("crab", "underwater image of a crab")])
    assert [t.presampler.tau_ss for t in pipe.topics] == [0.3, 0.3, 0.3]


def test_frames_stored_before_topics_go_to_the_default_topic_wherever_it_is_listed(two_topics, encoder):
    source = two_topics[0]
    old = [type(f)(**{**f.__dict__, "topic": ""}) for f in source.topic("fish").summary]  # no topic on disk
    cfg = Config.model_validate({"sampler": {"k": 3}, "gate": {"mode": "none"}, "queries": {
        "name": "main", "topics": [CORAL, {**FISH, "name": "main"}]}})
    pipe = Pipeline.from_config(cfg, encoder)
    assert pipe.restore(old) == []
    assert [f.image_index for f in pipe.topic("main").summary] == [f.image_index for f in old]
    assert pipe.topic("coral").summary == []


def test_the_command_line_query_replaces_the_topics_a_config_lists(tmp_path):
    import argparse

    from companion.commands.overrides import put_queries_and_encoder
    from companion.config import load_config

    config = tmp_path / "vehicle.yaml"
    config.write_text(json.dumps({"queries": {"topics": [FISH, CORAL]}}))
    args = argparse.Namespace(query="a shipwreck", negative=None, encoder=None, topic=None)
    over: dict = {}
    put_queries_and_encoder(over, args)
    cfg = load_config(config, overrides=over, environ={})
    assert [(t.name, t.positive) for t in cfg.queries.topic_list()] == [("main", "a shipwreck")]
    args.topic = [{"name": "wreck", "positive": "a shipwreck", "negatives": []}]  # --topic: topics again
    over = {}
    put_queries_and_encoder(over, args)
    assert [t.name for t in load_config(config, overrides=over, environ={}).queries.topic_list()] == ["wreck"]
