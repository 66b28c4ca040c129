"""The live companion with two topics, in process (no vehicle link): marks per topic, restarts, uploaded topics.

The cheap visual encoder has no text tower (every frame scores 1.0), so every frame enters both topics' summaries
and the tests are about where marks and frames go, not about what the frames show.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from companion.config import build_config
from companion.live.companion import LiveCompanion
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.storage.queries_file import QueriesFile, SavedQueries, topic_dicts
from companion.vision.feedback import MarkedPreSampler
from tests.waiting import wait_until
from vehicle.protocol.queries import QueryTopic

FISH = {"name": "fish", "positive": "underwater image with fish", "negatives": ["underwater image without fish"]}
CORAL = {"name": "coral", "positive": "underwater image of a coral reef", "negatives": ["underwater image of sand"]}


def _config(store: Path, topics=(FISH, CORAL)):
    return build_config({
        "source": {"uri": "synthetic://dive?seconds=2&width=160&height=96", "fps": 10, "realtime": True,
                   "loop": True},  # frames keep coming after a change
        "encoder": {"name": "visual"}, "queries": {"tau_ss": 0.5, "topics": list(topics)},
        "sampler": {"k": 3}, "mavlink": {"connection": None}, "store": {"dir": str(store)},
    })


def _start(store: Path, until=None, topics=(FISH, CORAL)) -> LiveCompanion:
    app = LiveCompanion(_config(store, topics))
    app.start()
    if until is not None:
        assert wait_until(lambda: until(app), 30), "frames stored"
    return app


def _both_hold(app: LiveCompanion) -> bool:
    with app.keeper.lock:
        return all(t.summary for t in app.pipeline.topics)


def _marks_of(app: LiveCompanion, name: str) -> tuple[int, int]:
    """(like, unlike) examples the topic's pre-sampler scores with."""
    presampler = app.pipeline.topic(name).presampler
    if not isinstance(presampler, MarkedPreSampler):
        return (0, 0)
    return len(presampler.examples.marks.like), len(presampler.examples.marks.unlike)


def test_a_mark_teaches_only_the_topic_of_its_frame(tmp_path: Path, caplog) -> None:
    store = tmp_path / "store"
    app = _start(store, until=_both_hold)
    try:
        fish = app.pipeline.topic("fish").summary[0].image_index
        coral = app.pipeline.topic("coral").summary[0].image_index
        with app.keeper.lock:  # between two changes: the status line's counts are the summaries'
            held = {t.name: len(t.summary) for t in app.pipeline.topics}
            assert f"summary fish {held['fish']}/3, coral {held['coral']}/3;" in app.status_line()
        app.on_marks([fish], [coral])  # as an upload of /config/marks.json does
        assert _marks_of(app, "fish") == (1, 0) and _marks_of(app, "coral") == (0, 1)
        report = app.report()
    finally:
        app.stop()
    assert set(report["topics"]) == {"fish", "coral"}
    saved = json.loads((store / "marks.json").read_text())
    assert saved["topics"] == {"fish": FISH["positive"], "coral": CORAL["positive"]}

    again = _start(store)  # saved marks come back, each to its topic
    again.stop()
    assert _marks_of(again, "fish") == (1, 0) and _marks_of(again, "coral") == (0, 1)

    marks = MarksFile(store / "marks.json")
    marks.save(SavedMarks([fish], [coral], FISH["positive"], {"fish": "underwater image of a turtle",
                                                              "coral": CORAL["positive"]}))
    with caplog.at_level(logging.INFO, logger="companion.live"):
        changed = _start(store)  # fish's query is not the one its mark was given under: coral's mark only
        changed.stop()
    assert _marks_of(changed, "fish") == (0, 0) and _marks_of(changed, "coral") == (0, 1)
    assert changed.marks.like == [] and changed.marks.unlike == [coral]
    assert f"not applied to image {fish} (topic fish)" in caplog.text

    marks.save(SavedMarks([fish], [coral], FISH["positive"]))  # a file from before topics: one query for all
    older = _start(store)
    older.stop()
    assert _marks_of(older, "fish") == (1, 0) and _marks_of(older, "coral") == (0, 0)


def test_uploaded_topics_survive_a_restart_until_the_configuration_changes(tmp_path: Path, caplog) -> None:
    store = tmp_path / "store"
    app = _start(store, until=_both_hold)
    try:
        def upload() -> None:  # on the keeper's thread, no batch in between: the upload's own change is checked
            fish = [f.image_index for f in app.pipeline.topic("fish").summary]
            app.on_queries([QueryTopic("fish", FISH["positive"], tuple(FISH["negatives"])),
                            QueryTopic("wreck", "underwater image of a wreck", ("underwater image of sand",))])
            assert [t.name for t in app.pipeline.topics] == ["fish", "wreck"]
            assert [f.image_index for f in app.pipeline.topic("fish").summary] == fish
            assert app.store.summary == fish

        app.keeper.submit(upload)
        assert wait_until(lambda: _both_hold(app), 30), "wreck frames stored"
    finally:
        app.stop()
    held = {t.name: [f.image_index for f in t.summary] for t in app.pipeline.topics}
    saved = json.loads((store / "queries.json").read_text())
    assert [t["name"] for t in saved["topics"]] == ["fish", "wreck"]
    assert [t["name"] for t in saved["configured"]] == ["fish", "coral"]

    # a restart on the same configuration goes on with the uploaded topics and the frames they hold
    with caplog.at_level(logging.INFO, logger="companion.live"):
        again = _start(store)
        again.stop()
    assert [t.name for t in again.pipeline.topics] == ["fish", "wreck"]
    assert again.pipeline.topic("wreck").presampler.positive == "underwater image of a wreck"
    resumed = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("resumed topics:"))
    assert resumed.startswith(f"resumed topics: fish {held['fish']}; wreck {held['wreck']}"), resumed
    assert set(held["fish"] + held["wreck"]) <= set(again.store.summary)
    assert "left the summary" not in caplog.text

    # someone changed the configuration since the upload: it wins, and wreck's frames leave (said so)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="companion.live"):
        third = _start(store, topics=(FISH, {**CORAL, "positive": "underwater image of corals"}))
        third.stop()
    assert [t.name for t in third.pipeline.topics] == ["fish", "coral"]
    assert "configuration's topics changed since that upload" in caplog.text
    assert "frames of topic(s) wreck left the summary" in caplog.text
    wreck_now = [f.image_index for f in again.pipeline.topic("wreck").summary]
    assert not set(wreck_now) & set(third.store.summary)


def test_selective_enhancement_serves_every_topic_and_follows_their_changes(tmp_path: Path) -> None:
    cfg = _config(tmp_path / "store", (FISH, {**CORAL, "tau_ss": 0.2}))
    cfg = build_config({**cfg.model_dump(), "enhance": {"mode": "selective", "method": "classic", "tau_ses": 0.4}})
    app = LiveCompanion(cfg)
    app.start()
    try:
        assert wait_until(lambda: _both_hold(app), 30), "enhanced frames in both topics"
        assert app.selective.raw.names == ["fish", "coral"]
        assert [app.selective.raw.tau_of(n) for n in ("fish", "coral")] == [0.5, 0.2]
        assert [t.presampler.tau_ss for t in app.pipeline.topics] == [0.4, 0.4]  # enhanced frames face tau_ses
        app.on_param("MERL_ENHANCE", 0)  # off: each topic's pipeline gate is its own tau_ss again
        assert [t.presampler.tau_ss for t in app.pipeline.topics] == [0.5, 0.2]
        app.on_param("MERL_ENHANCE", 1)
        app.on_queries([QueryTopic("fish", FISH["positive"], tuple(FISH["negatives"])),
                         QueryTopic("wreck", "underwater image of a wreck", ("underwater image of sand",))])
        assert app.selective.raw.names == ["fish", "wreck"] == [t.name for t in app.pipeline.topics]
        doc = app.keeper_document()
    finally:
        app.stop()
    sidecars = [json.loads(p.read_text()) for p in (tmp_path / "store" / "frames").glob("*.json")]
    assert {"fish", "coral"} <= {s["topic"] for s in sidecars} <= {"fish", "coral", "wreck"}
    assert any(s["enhanced"] for s in sidecars)  # (MERL_ENHANCE was off for a moment)
    # the raw frames once each, their enhanced versions once more: still one pass for both topics
    assert doc["encoder"]["images"] == doc["encoder"]["scored"] and doc["encoder"]["marks"] == 0


def test_an_upload_this_encoder_cannot_read_is_given_up_at_restart_for_the_configured_topics(tmp_path: Path,
                                                                                           caplog) -> None:
    """Topics uploaded under one encoder (CLIP reads any words) and a restart under the packaged one, which does
    not know a word of them: the companion starts with its configured topics and says why, instead of failing
    every start until someone deletes queries.json."""
    store = tmp_path / "store"
    cfg = build_config({"source": {"uri": "synthetic://dive?seconds=2&width=160&height=96", "fps": 10},
                        "encoder": {"name": "imagenet"}, "queries": {"topics": [FISH]},
                        "mavlink": {"connection": None}, "store": {"dir": str(store)}})
    saved = QueriesFile(store / "queries.json", version="0.1.0")
    saved.save(SavedQueries(topics=[{"name": "odd", "positive": "a blorptang on the sea floor", "negatives": []}],
                            configured=topic_dicts(cfg.queries.topic_list())))
    app = LiveCompanion(cfg)
    with caplog.at_level(logging.WARNING):
        app.start()
    try:
        assert [t.name for t in app.pipeline.topics] == ["fish"]
        assert app.cfg.queries.topic_list()[0].positive == FISH["positive"]
        assert f"{store / 'queries.json'}: saved queries not followed, following the configuration: 'blorptang'" \
            in caplog.text
    finally:
        app.stop()

