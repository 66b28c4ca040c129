"""The link's writer thread: one thread writes, in the order handed over, drains on stop, and a stall is bounded."""

from __future__ import annotations

import threading

from vehicle.link import packet_writer
from vehicle.link.packet_writer import PacketWriter


class _Wire:
    def __init__(self, hold: threading.Event | None = None) -> None:
        self.items: list[tuple[str, int]] = []
        self.threads: set[str] = set()
        self.hold = hold

    def write(self, item: tuple[str, int]) -> int:
        if self.hold is not None:
            self.hold.wait(10)
        self.threads.add(threading.current_thread().name)
        self.items.append(item)
        return 10 + item[1]


def test_senders_on_many_threads_are_written_on_one_thread_each_in_its_own_order():
    wire = _Wire()
    writer = PacketWriter(wire.write, "test-tx")
    writer.start()
    sent: dict[str, list[int]] = {}

    def sender(name: str) -> None:
        sent[name] = [writer.send((name, i)) for i in range(200)]

    threads = [threading.Thread(target=sender, args=(f"s{k}",)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    writer.stop()
    assert wire.threads == {"test-tx"}
    assert len(wire.items) == 800
    for name, counts in sent.items():
        assert counts == [10 + i for i in range(200)]  # each sender got its own packet's byte count
        assert [i for n, i in wire.items if n == name] == list(range(200))


def test_stop_writes_what_was_handed_over_and_later_sends_go_out_on_the_callers_thread():
    hold = threading.Event()
    wire = _Wire(hold)
    writer = PacketWriter(wire.write, "test-tx")
    writer.start()
    results: list[int] = []
    senders = [threading.Thread(target=lambda i=i: results.append(writer.send(("a", i)))) for i in range(3)]
    for t in senders:
        t.start()
    stopper = threading.Thread(target=writer.stop)
    stopper.start()
    hold.set()  # the wire frees up only after stop was asked
    stopper.join(10)
    for t in senders:
        t.join(10)
    assert sorted(i for _, i in wire.items) == [0, 1, 2] and sorted(results) == [10, 11, 12]
    assert writer.send(("late", 5)) == 15 and wire.items[-1] == ("late", 5)
    assert threading.current_thread().name in wire.threads


def test_a_stalled_wire_holds_a_sender_no_longer_than_the_send_wait(monkeypatch):
    monkeypatch.setattr(packet_writer, "SEND_WAIT_S", 0.2)
    hold = threading.Event()
    wire = _Wire(hold)
    writer = PacketWriter(wire.write, "test-tx")
    writer.start()
    try:
        assert writer.send(("stuck", 1)) == 0  # not written yet: nothing is charged
    finally:
        hold.set()
        writer.stop()
    assert wire.items == [("stuck", 1)]  # it still went out once the wire moved


def test_a_send_racing_stop_is_written_once_and_never_left_waiting():
    wire = _Wire()
    for _ in range(300):
        writer = PacketWriter(wire.write, "test-tx")
        writer.start()
        go = threading.Barrier(3)
        results: list[int] = []

        def sender(writer: PacketWriter = writer, go: threading.Barrier = go, results: list[int] = results) -> None:
            go.wait()
            results.extend(writer.send(("r", 1)) for _ in range(3))

        senders = [threading.Thread(target=sender) for _ in range(2)]
        for t in senders:
            t.start()
        go.wait()
        writer.stop()
        for t in senders:
            t.join(10)
        assert results == [11] * 6  # each written, each charged: none queued after the loop had ended
    assert len(wire.items) == 1800
