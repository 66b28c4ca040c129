"""A tiny MAVLink-agnostic UDP hub: what BlueOS' router does on a vehicle, for the extension, demo, tests and benches.

Every datagram from one peer goes to every other peer. Peers are learnt from the first datagram they send
(``udpout:`` clients: the simulated autopilot, the companion) or given up front (a surface tool listening with
``udpin:``, the vehicle's router). Datagrams are forwarded whole, so MAVLink framing, CRCs and signing pass through
untouched.

A learnt peer is forgotten once it has been silent for ``forget_after_s`` (every MAVLink peer sends a heartbeat a
second), and at most ``max_peers`` are kept, the longest silent going first. Without that, each restart of a client
(a new ephemeral port) left a dead peer behind that every later datagram was still sent to: a helper measured a hub
with 15 of them fall behind a 3,300-datagram/s flood and drop the companion's heartbeats from its socket (gaps of
2.1 s, 600 packets lost), while the companion itself sent on time.

A learnt peer whose port is closed (the client exited; its host answers "port unreachable") is forgotten at once,
on Linux: the hub asks the kernel for its ICMP errors (``IP_RECVERR``), whose queue names the address each refused
datagram was sent to. Otherwise a burst of one-shot clients left up to a minute of dead peers, and with 30 of them
a flood still cost the hub 492 datagrams. Peers given up front are kept: a listener may not have started yet.
"""

from __future__ import annotations

import logging
import selectors
import socket
import sys
import threading
import time
from collections.abc import Callable

from vehicle.link.endpoint import ask_receive_buffer

log = logging.getLogger(__name__)

FORGET_AFTER_S = 60.0
"""A learnt peer silent this long is forgotten (it is learnt again by its next datagram)."""
MAX_PEERS = 64
"""Learnt peers kept at most; more senders than this push out the longest silent."""
RECEIVE_BUFFER = 1 << 20
"""Bytes the kernel may hold for the hub while it forwards: a burst waits instead of being dropped."""
_IP_RECVERR = getattr(socket, "IP_RECVERR", 11)  # linux/in.h; Python's socket module does not name it
_ERRORS_AT_ONCE = 64
_RECEIVE_WAIT_S = 0.2
_SEND_TRIES = 8
"""A send failed by refusals of earlier datagrams (each arriving since the last was read) is tried this often."""


class UdpHub:
    def __init__(self, host: str = "127.0.0.1", port: int = 0, outputs: list[tuple[str, int]] | None = None, *,
                 forget_after_s: float = FORGET_AFTER_S, max_peers: int = MAX_PEERS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        got = ask_receive_buffer(self.sock, RECEIVE_BUFFER)
        if got < RECEIVE_BUFFER:
            log.info("udp hub: receive buffer %d KB of the %d KB asked (net.core.rmem_max caps it)", got // 1024,
                     RECEIVE_BUFFER // 1024)
        self._hears_refusals = sys.platform == "linux"
        if self._hears_refusals:
            try:
                self.sock.setsockopt(socket.IPPROTO_IP, _IP_RECVERR, 1)
            except OSError:
                self._hears_refusals = False  # peers are then forgotten by silence only
        self.sock.bind((host, port))
        self.sock.setblocking(False)  # waits are the selector's: the error queue is then read without a mode switch
        self._readable = selectors.DefaultSelector()
        self._readable.register(self.sock, selectors.EVENT_READ)
        self._writable = selectors.DefaultSelector()
        self._writable.register(self.sock, selectors.EVENT_WRITE)
        self.host, self.port = self.sock.getsockname()[:2]
        self.outputs: list[tuple[str, int]] = list(outputs or [])
        """Given up front: always sent to, never forgotten."""
        self.forget_after_s = forget_after_s
        self.max_peers = max_peers
        self.clock = clock
        self._heard: dict[tuple[str, int], float] = {}  # learnt peer -> when it last sent
        self.forwarded = 0
        self.bytes = 0
        self.forgotten = 0
        self.refused = 0
        """Learnt peers forgotten because their port was closed."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def url(self) -> str:
        """The connection string a client uses to join (``udpout:``)."""
        return f"udpout:{self.host}:{self.port}"

    @property
    def peers(self) -> list[tuple[str, int]]:
        """Where a datagram may go now: the outputs, then the learnt peers, the longest silent first."""
        with self._lock:
            return self.outputs + list(self._heard)  # an output is never learnt

    def start(self) -> UdpHub:
        self._thread = threading.Thread(target=self._run, name="udp-hub", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, sender = self.sock.recvfrom(65535)
            except BlockingIOError:  # nothing queued: wait for some (under a flood there is always some)
                if not self._readable.select(_RECEIVE_WAIT_S):
                    self._learn(None)
                continue
            except OSError:
                if self._stop.is_set():
                    return
                self._forget_refused()  # a refusal reported here; the error queue says whose
                continue
            for peer in self._learn(sender):
                self._send(data, peer)

    def _send(self, data: bytes, peer: tuple[str, int]) -> None:
        for _ in range(_SEND_TRIES):
            try:
                self.sock.sendto(data, peer)
            except BlockingIOError:  # the send buffer is full: wait for room, as a blocking send would
                self._writable.select(_RECEIVE_WAIT_S)
                continue
            except OSError as error:
                # With IP_RECVERR a refusal of an earlier datagram, to any peer, fails this send once: forget
                # whoever refused, then send again, unless this peer refused or no refusal explains the failure.
                # ECONNREFUSED is always such a refusal (an unconnected socket's own send is never refused), even
                # when the queue is empty: with the receive buffer full the kernel drops the error's entry but
                # still fails the next send, which a flood past a closed output did to 2,700 live datagrams of 10,000
                named = self._forget_refused()
                if peer in named or not (named or isinstance(error, ConnectionRefusedError)):
                    return
                continue
            self.forwarded += 1
            self.bytes += len(data)
            return

    def _forget_refused(self) -> set[tuple[str, int]]:
        """Read the kernel's queued ICMP errors and forget the learnt peers they name; the addresses named."""
        named: set[tuple[str, int]] = set()
        if not self._hears_refusals:
            return named
        for _ in range(_ERRORS_AT_ONCE):
            try:
                _data, _anc, _flags, address = self.sock.recvmsg(1, 512, socket.MSG_ERRQUEUE)
            except OSError:  # empty (BlockingIOError) or unreadable: what was read is what there is
                break
            named.add(address[:2])
        with self._lock:
            for peer in named:
                if self._heard.pop(peer, None) is not None:
                    self.refused += 1
                    self.forgotten += 1
        return named

    def _learn(self, sender: tuple[str, int] | None) -> list[tuple[str, int]]:
        """Note that ``sender`` spoke, forget the peers silent too long, and say where its datagram goes."""
        now = self.clock()
        with self._lock:
            if sender is not None and sender not in self.outputs:
                self._heard.pop(sender, None)
                self._heard[sender] = now  # most recently heard last
            while self._heard:  # the longest silent first: it goes when silent too long or one too many
                oldest, heard = next(iter(self._heard.items()))
                if now - heard <= self.forget_after_s and len(self._heard) <= self.max_peers:
                    break
                del self._heard[oldest]
                self.forgotten += 1
            return [p for p in self.outputs + list(self._heard) if p != sender]

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        self._readable.close()
        self._writable.close()
        self.sock.close()
