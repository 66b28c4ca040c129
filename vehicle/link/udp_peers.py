"""A ``udpin:`` transport that answers at most ``MAX_PEERS`` peers, keeping the ones that speak.

pymavlink's UDP server learns every source address a datagram comes from and sends each later packet to all of
them, forever: a device on the tether sending one datagram from each of a thousand ports made every heartbeat,
reply and capture go out a thousand times, and the table never shrank. Here a new address is learnt only while
fewer than ``max_peers`` are known, or in place of the longest-silent one once that has been silent for
``replace_after_s``; a peer that keeps speaking keeps its place, so a flood of new addresses cannot push the
ground station or the router out. What a refused address sends is still read; it is only not answered.
"""

from __future__ import annotations

import errno
import logging
import time
from collections.abc import Callable

from pymavlink import mavutil

log = logging.getLogger(__name__)

MAX_PEERS = 16
REPLACE_AFTER_S = 10.0
"""A known peer silent this long may give its place to a new one (every MAVLink peer sends a 1 Hz heartbeat)."""
_NO_DATA = (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED)


class BoundedUdpServer(mavutil.mavudp):
    """``mavutil.mavudp`` listening on ``address`` (HOST:PORT) whose peer table (``clients``) holds ``max_peers``
    at most. Called on the link's receive thread; the writer thread iterates ``clients``, so the set is replaced,
    never changed in place."""

    def __init__(self, address: str, *, source_system: int, source_component: int, max_peers: int = MAX_PEERS,
                 replace_after_s: float = REPLACE_AFTER_S, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(address, input=True, source_system=source_system, source_component=source_component)
        self.max_peers = max_peers
        self.replace_after_s = replace_after_s
        self._clock = clock
        self._heard: dict[tuple[str, int], float] = {}
        self.refused_peers = 0
        """Datagrams from an address not learnt because the table was full of peers that speak."""
        self.last_peer: tuple[str, int] | None = None
        """The address the last datagram came from (the link tags what it parses from it)."""

    def recv(self, n=None) -> bytes:
        try:
            data, address = self.port.recvfrom(mavutil.UDP_MAX_PACKET_LEN)
        except OSError as err:
            if err.errno in _NO_DATA:
                return b""
            raise
        self.last_peer = address
        self._learn(address)
        return data

    def _learn(self, address: tuple[str, int]) -> None:
        now = self._clock()
        if address in self._heard:
            self._heard[address] = now
            return
        if len(self._heard) >= self.max_peers:
            quietest = min(self._heard, key=self._heard.__getitem__)
            if now - self._heard[quietest] < self.replace_after_s:
                self.refused_peers += 1
                if self.refused_peers == 1:
                    log.warning("udpin:%s: %d peers speak already; %s:%d is read but not answered (nor any further "
                                "new address while they speak)", self.address, self.max_peers, *address)
                return
            del self._heard[quietest]
        self._heard[address] = now
        self.clients = set(self._heard)  # a new set: the writer thread may be iterating the old one
