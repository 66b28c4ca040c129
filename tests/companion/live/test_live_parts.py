"""Small parts of the live companion: the drop-oldest queue and the UDP hub that plays the router."""

from __future__ import annotations

import socket
import threading

from companion.live.queues import DropOldestQueue
from companion.live.udp_hub import UdpHub


def test_queue_drops_the_oldest_and_counts_it() -> None:
    q: DropOldestQueue[int] = DropOldestQueue(3)
    assert all(q.put(i) for i in range(3))
    assert q.put(3) is False and q.put(4) is False
    assert q.dropped == 2 and len(q) == 3
    assert q.get_batch(2, timeout=0) == [2, 3]
    assert q.get_batch(8, timeout=0) == [4]
    assert q.get_batch(8, timeout=0.01) == []


def test_queue_wakes_a_waiting_reader_and_close_releases_it() -> None:
    q: DropOldestQueue[str] = DropOldestQueue(2)
    got: list[list[str]] = []
    reader = threading.Thread(target=lambda: got.append(q.get_batch(4, timeout=30)))
    reader.start()
    q.put("frame")
    reader.join(10)
    assert got == [["frame"]]
    reader = threading.Thread(target=lambda: got.append(q.get_batch(4, timeout=30)))
    reader.start()
    q.close()
    reader.join(10)
    assert not reader.is_alive() and got[-1] == []


def test_hub_forwards_every_datagram_to_every_other_peer() -> None:
    listen = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listen.bind(("127.0.0.1", 0))
    listen.settimeout(5)
    hub = UdpHub(outputs=[listen.getsockname()]).start()
    a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for s in (a, b):
        s.settimeout(5)
    try:
        a.sendto(b"from-a", (hub.host, hub.port))
        assert listen.recv(100) == b"from-a"
        b.sendto(b"from-b", (hub.host, hub.port))
        assert listen.recv(100) == b"from-b"
        assert a.recv(100) == b"from-b"  # a was learnt from its first datagram
        listen.sendto(b"from-surface", (hub.host, hub.port))
        assert a.recv(100) == b"from-surface" and b.recv(100) == b"from-surface"
    finally:
        hub.stop()
        for s in (a, b, listen):
            s.close()


def test_fps_can_be_read_while_the_inference_thread_appends() -> None:
    from companion.live.loops import LiveCounters

    counters = LiveCounters()
    stop = threading.Event()

    def inference() -> None:
        t = 0.0
        while not stop.is_set():
            t += 0.01
            counters.recent.append(t)

    writer = threading.Thread(target=inference, daemon=True)
    writer.start()
    try:
        for _ in range(20000):  # iterating the live deque raised "deque mutated during iteration" here
            assert counters.fps(now=1e9) == 0.0  # every time is too old at this "now"
    finally:
        stop.set()
        writer.join(timeout=5)
