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
