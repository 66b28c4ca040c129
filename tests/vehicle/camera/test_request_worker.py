"""The request worker: the receive loop's hand-off never waits, even while a slow request is being served."""

from __future__ import annotations

import threading

from vehicle.camera.request_worker import RequestWorker


def test_submit_returns_while_a_slow_job_runs_and_a_full_queue_drops():
    worker = RequestWorker("test-worker", limit=2)
    assert not worker.submit(lambda: None)  # not started: refused, not queued forever
    worker.start()
    release, started, order = threading.Event(), threading.Event(), []

    def slow() -> None:
        started.set()
        release.wait(10)
        order.append("slow")

    assert worker.submit(slow)
    assert started.wait(10)
    assert worker.submit(lambda: order.append("a")) and worker.submit(lambda: order.append("b"))
    assert not worker.submit(lambda: order.append("c"))  # the queue (2) is full: dropped and counted
    assert worker.dropped == 1 and order == []
    worker.submit(lambda: 1 / 0)  # dropped too; a failing job would be logged, not kill the worker
    release.set()
    done = threading.Event()
    while not worker.submit(done.set):
        pass
    assert done.wait(10)
    assert order == ["slow", "a", "b"] and worker.served >= 3
    worker.stop()
    assert not worker.submit(lambda: None)


def test_unsigned_requests_filling_their_queue_never_push_out_a_signed_one_which_is_served_first(caplog):
    """Strangers flooding unsigned requests (each within its rate, from many made-up ids) fill only their own
    queue: the operator's signed request is still queued, served before them, and the drops are logged once."""
    worker = RequestWorker("test-worker", limit=3)
    worker.start()
    release, started, order = threading.Event(), threading.Event(), []

    def slow() -> None:
        started.set()
        release.wait(10)

    assert worker.submit(slow, signed=True)
    assert started.wait(10)
    with caplog.at_level("WARNING", logger="vehicle.camera.request_worker"):
        accepted = [worker.submit(lambda i=i: order.append(f"stranger{i}")) for i in range(2000)]
    assert sum(accepted) == 3 and worker.dropped == 1997
    assert len([r for r in caplog.records if "request queue full" in r.getMessage()]) == 1  # not one per 100
    assert worker.submit(lambda: order.append("operator"), signed=True)
    done = threading.Event()
    release.set()
    while not worker.submit(done.set):
        pass
    assert done.wait(10)
    assert order == ["operator", "stranger0", "stranger1", "stranger2"]
    worker.stop()
