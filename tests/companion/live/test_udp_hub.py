"""The UDP hub (BlueOS' router stand-in in the extension, demo, tests and benches) with real sockets on 127.0.0.1:
peers that fall silent or close their port are forgotten, the table stays bounded, and outputs given up front
always get traffic."""

from __future__ import annotations

import socket
import sys
from collections.abc import Iterator

import pytest

from companion.live.udp_hub import UdpHub
from tests.waiting import wait_until


def _socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(2.0)
    return s


def _received(sock: socket.socket) -> list[bytes]:
    """Everything queued on the socket now (the hub has already forwarded what it will)."""
    sock.setblocking(False)
    out = []
    try:
        while True:
            out.append(sock.recv(65535))
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(2.0)
    return out


@pytest.fixture
def clock() -> list[float]:
    return [1000.0]


@pytest.fixture
def hub(clock: list[float]) -> Iterator[UdpHub]:
    hub = UdpHub(forget_after_s=10.0, max_peers=4, clock=lambda: clock[0]).start()
    yield hub
    hub.stop()


def _say(hub: UdpHub, sock: socket.socket, data: bytes, to: int) -> None:
    """Send through the hub and wait until it has learnt the sender and forwarded the datagram to ``to`` peers."""
    before = hub.forwarded
    sock.sendto(data, (hub.host, hub.port))
    assert wait_until(lambda: sock.getsockname() in hub.peers and hub.forwarded >= before + to), \
        f"the hub did not forward {data!r} to {to}"
    assert hub.forwarded == before + to


def test_a_silent_peer_is_forgotten_and_learnt_again_when_it_speaks(clock: list[float]) -> None:
    output = _socket()
    hub = UdpHub(outputs=[output.getsockname()], forget_after_s=10.0, clock=lambda: clock[0]).start()
    a, b = _socket(), _socket()
    try:
        _say(hub, a, b"a1", to=1)
        _say(hub, b, b"b1", to=2)
        assert hub.peers == [output.getsockname(), a.getsockname(), b.getsockname()]
        assert a.recv(100) == b"b1" and _received(b) == []  # b joined after a1
        clock[0] += 11.0  # b, like a client that restarted on another port, says nothing more
        _say(hub, a, b"a2", to=1)
        assert hub.peers == [output.getsockname(), a.getsockname()] and hub.forgotten == 1
        _say(hub, a, b"a3", to=1)
        assert _received(b) == []  # nothing more is sent to the silent peer
        assert _received(output) == [b"a1", b"b1", b"a2", b"a3"]  # the output, silent throughout, gets it all
        _say(hub, b, b"b2", to=2)  # it speaks again: learnt again
        _say(hub, a, b"a4", to=2)
        assert b.recv(100) == b"a4" and a.recv(100) == b"b2"
    finally:
        hub.stop()
        for s in (output, a, b):
            s.close()


def test_many_senders_keep_at_most_max_peers_the_longest_silent_going_first(hub: UdpHub, clock: list[float]) -> None:
    senders = [_socket() for _ in range(7)]
    try:
        for i, s in enumerate(senders[:5]):
            clock[0] += 1.0
            _say(hub, s, b"hello %d" % i, to=min(i, 3))
        names = [s.getsockname() for s in senders]
        assert hub.peers == names[1:5] and hub.forgotten == 1  # four kept: the first sender went
        clock[0] += 1.0
        _say(hub, senders[1], b"again", to=3)  # now the most recently heard
        clock[0] += 1.0
        _say(hub, senders[5], b"new", to=3)
        assert hub.peers == [names[3], names[4], names[1], names[5]]  # senders[2], silent longest, went
        assert _received(senders[2]) == [b"hello 3", b"hello 4", b"again"]  # nothing after it went
        assert _received(senders[3]) == [b"hello 4", b"again", b"new"]
        clock[0] += 1.0
        _say(hub, senders[6], b"newer", to=3)
        assert len(hub.peers) == 4 and names[3] not in hub.peers and hub.forgotten == 3
    finally:
        for s in senders:
            s.close()


@pytest.mark.skipif(sys.platform != "linux", reason="the hub reads ICMP errors with Linux's IP_RECVERR")
def test_a_peer_whose_port_closed_is_forgotten_at_once_and_the_live_peers_lose_nothing(clock: list[float]) -> None:
    early = _socket()
    output = early.getsockname()
    early.close()  # a surface tool given up front that has not started listening yet
    hub = UdpHub(outputs=[output], forget_after_s=10.0, clock=lambda: clock[0]).start()
    a, b, gone = _socket(), _socket(), _socket()
    listener = None
    try:
        _say(hub, gone, b"hello", to=1)
        _say(hub, b, b"hello", to=2)
        _say(hub, a, b"hello", to=3)
        gone_address = gone.getsockname()
        gone.close()  # the client exits; no clock moves, so only its closed port can tell
        _received(b)
        sent = [b"m%d" % i for i in range(30)]
        for data in sent:
            a.sendto(data, (hub.host, hub.port))
        got: list[bytes] = []
        assert wait_until(lambda: got.extend(_received(b)) or len(got) >= len(sent), 5), f"b got {got}"
        assert got == sent  # every datagram, in order, though the refusals were reported on sends to b
        assert gone_address not in hub.peers and hub.refused == 1 and hub.forgotten == 1
        assert hub.peers == [output, b.getsockname(), a.getsockname()]  # the output, refusing too, is kept
        listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        listener.bind(output)  # the surface tool starts
        listener.settimeout(2.0)
        a.sendto(b"now", (hub.host, hub.port))
        assert listener.recv(100) == b"now" and b.recv(100) == b"now"
    finally:
        hub.stop()
        for s in (a, b, listener):
            if s is not None:
                s.close()


@pytest.mark.skipif(sys.platform != "linux", reason="the hub reads ICMP errors with Linux's IP_RECVERR")
def test_a_refusal_whose_report_the_full_buffer_dropped_does_not_lose_the_next_send() -> None:
    early = _socket()
    output = early.getsockname()
    early.close()  # an output given up front, not listening
    hub = UdpHub(outputs=[output])  # not started: its receive buffer is filled first, as by a flood
    flood, live = _socket(), _socket()
    try:
        for _ in range(5000):  # far past the hub's buffer; the rest is dropped by the kernel
            flood.sendto(b"x" * 1000, (hub.host, hub.port))
        hub._send(b"to the output", output)  # refused; the buffer being full, the kernel drops the error's entry
        hub._send(b"to a live peer", live.getsockname())  # this send fails on that refusal, with nothing queued
        assert live.recv(100) == b"to a live peer"
        assert hub.forwarded == 2
    finally:
        hub.stop()
        flood.close()
        live.close()
