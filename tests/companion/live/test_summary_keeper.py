"""The summary keeper in-process: changes from several threads at once leave the store equal to the summary.

A real pipeline (the packaged visual encoder, generated frames) and a real store in a temporary directory; one
thread feeds batches, others change K, the queries and tau_ss at the same time, as the inference loop, the
enhancer worker and the surface link do in the live companion.
"""

from __future__ import annotations

import json
import threading
from itertools import islice
from pathlib import Path

from companion.config import Config, StoreConfig
from companion.live.summary_keeper import ChangeTimeout, SummaryKeeper
from companion.sources.synthetic import SyntheticSource
from companion.storage.store import Store
from companion.vision.encoders.factory import make_encoder
from companion.vision.pipeline import Pipeline


def test_concurrent_changes_keep_the_store_equal_to_the_summary(tmp_path: Path) -> None:
    cfg = Config.model_validate({"encoder": {"name": "visual"}, "sampler": {"k": 6}, "queries": {"tau_ss": 0}})
    pipeline = Pipeline.from_config(cfg, make_encoder(cfg.encoder))
    store = Store(StoreConfig(dir=str(tmp_path)))
    keeper = SummaryKeeper(pipeline, store, tags=lambda frame: {"query": pipeline.presampler.positive})
    frames = list(islice(SyntheticSource("synthetic://dive?seconds=2&width=96&height=64", fps=10, realtime=False),
                         80))  # an endless dive: 80 frames of it, four scenes
    done = threading.Event()
    errors: list[BaseException] = []

    def feed() -> None:
        try:
            for start in range(0, len(frames), 4):
                keeper.change(lambda s=start: pipeline.process(frames[s:s + 4]), lambda o: o.events)
        except BaseException as err:  # noqa: BLE001 - reported by the test below
            errors.append(err)
        finally:
            done.set()

    def tune() -> None:
        i = 0
        while not done.is_set():
            k = (2, 5, 3, 8, 4)[i % 5]
            keeper.change(lambda k=k: pipeline.set_k(k))
            keeper.change(lambda i=i: pipeline.presampler.set_queries(f"query {i % 3}", ["water"]))
            i += 1
            done.wait(0.01)

    threads = [threading.Thread(target=feed), threading.Thread(target=tune), threading.Thread(target=tune)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    doc = keeper.document()
    assert doc["mismatches"] == 0 and doc["applied"] > 0
    assert store.summary == keeper.held() == doc["summary"]
    lines = [json.loads(line) for line in (tmp_path / "changes.jsonl").read_text().splitlines()]
    assert len(lines) == keeper.applied
    for applied, summary in doc["history"]:
        assert lines[applied - 1]["summary"] == summary
    assert Store(StoreConfig(dir=str(tmp_path))).summary == keeper.held(), "what a restart would resume"


def _keeper(tmp_path: Path) -> tuple[SummaryKeeper, Pipeline]:
    cfg = Config.model_validate({"encoder": {"name": "visual"}, "sampler": {"k": 6}, "queries": {"tau_ss": 0}})
    pipeline = Pipeline.from_config(cfg, make_encoder(cfg.encoder))
    return SummaryKeeper(pipeline, Store(StoreConfig(dir=str(tmp_path))), tags=lambda frame: {}), pipeline


def test_submitted_changes_run_on_the_keepers_thread_in_order_and_errors_reach_the_submitter(tmp_path) -> None:
    keeper, pipeline = _keeper(tmp_path)
    keeper.start()
    try:
        ran: list[tuple[str, int]] = []

        def change(k: int) -> list:
            ran.append((threading.current_thread().name, k))
            return pipeline.set_k(k)

        threads = [threading.Thread(target=keeper.submit, args=(lambda k=k: change(k),)) for k in (3, 4, 5)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert {name for name, _ in ran} == {"summary-keeper"} and sorted(k for _, k in ran) == [3, 4, 5]
        no_events = lambda _result: []  # noqa: E731 - these changes return a name, not summary events
        nested = keeper.submit(lambda: keeper.submit(lambda: threading.current_thread().name, no_events), no_events)
        assert nested == "summary-keeper"  # a change that submits another runs it at once, not deadlocked

        def refuse() -> None:
            raise ValueError("image 7 is not in the store")

        try:
            keeper.submit(refuse)
        except ValueError as err:
            assert str(err) == "image 7 is not in the store"
        else:
            raise AssertionError("the change's error must reach its submitter")
    finally:
        keeper.stop()


def test_a_change_that_cannot_start_in_time_is_withdrawn_and_never_applied(tmp_path) -> None:
    keeper, pipeline = _keeper(tmp_path)
    keeper.start()
    applied = threading.Event()
    try:
        with keeper.lock:  # a batch that does not end within the submitter's patience
            try:
                keeper.submit(lambda: applied.set(), timeout=0.2)
            except ChangeTimeout as err:
                assert "busy" in str(err)
            else:
                raise AssertionError("expected ChangeTimeout")
        assert keeper.submit(lambda: "after", lambda _result: []) == "after"  # the queue goes on past the withdrawn change
        assert not applied.is_set()
    finally:
        keeper.stop()
