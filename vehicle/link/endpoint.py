"""Where a MAVLink connection goes: the connection string, checked up front, and the transport it opens.

pymavlink's ``mavutil`` opens every transport; this module adds what it lacks for a connection that must stay up
for hours: a typo is a one-line error before any thread starts, a stalled serial port cannot hold up a sender,
a UDP socket has room for a burst while its reader is descheduled, and a UDP server answers a bounded number of
peers (``udp_peers``).
"""

from __future__ import annotations

import errno
import logging
import socket
import sys
from dataclasses import dataclass

from pymavlink import mavutil

from vehicle.errors import UsageError
from vehicle.link.udp_peers import BoundedUdpServer

log = logging.getLogger(__name__)

_SCHEMES = ("udpin", "udpout", "tcp", "tcpin")
_SERIAL_WRITE_TIMEOUT_S = 0.2
_UDP_RCVBUF = 1 << 20  # a parameter download, a busy router


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string: ``scheme`` is udpin | udpout | tcp | tcpin | serial."""

    scheme: str
    address: str
    baud: int = 115200

    @property
    def reconnects(self) -> bool:
        """TCP client and serial links are re-opened after a failure; UDP and TCP servers just wait."""
        return self.scheme in ("tcp", "serial")

    @property
    def is_udp(self) -> bool:
        return self.scheme.startswith("udp")

    @property
    def is_tcp(self) -> bool:
        return self.scheme in ("tcp", "tcpin")

    def __str__(self) -> str:
        return f"{self.address},{self.baud}" if self.scheme == "serial" else f"{self.scheme}:{self.address}"


def parse_connection(connection: str) -> Endpoint:
    """Check a connection string up front so a typo is a one-line error, not a thread dying later."""
    text = (connection or "").strip()
    scheme, sep, rest = text.partition(":")
    if sep and scheme in _SCHEMES:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise UsageError(f"mavlink connection {connection!r}: expected {scheme}:HOST:PORT")
        return Endpoint(scheme, f"{host}:{int(port)}")
    if text.startswith("/") or text.upper().startswith("COM"):
        device, _, baud = text.partition(",")
        if baud and not baud.isdigit():
            raise UsageError(f"mavlink connection {connection!r}: baud rate must be a number")
        return Endpoint("serial", device, int(baud) if baud else 115200)
    raise UsageError(
        f"mavlink connection {connection!r}: expected udpin:, udpout:, tcp:, tcpin:HOST:PORT or /dev/DEVICE,BAUD"
    )


def open_transport(endpoint: Endpoint, system_id: int, component_id: int, name: str) -> mavutil.mavfile:
    """Open ``endpoint`` with pymavlink; raises what the transport raises (the caller retries)."""
    kwargs = {"source_system": system_id, "source_component": component_id}
    if endpoint.scheme == "serial":
        conn = mavutil.mavlink_connection(endpoint.address, baud=endpoint.baud, **kwargs)
        conn.port.write_timeout = _SERIAL_WRITE_TIMEOUT_S  # a stalled port must not hold up a sender
        return conn
    if endpoint.scheme == "tcp":
        return mavutil.mavlink_connection(f"tcp:{endpoint.address}", retries=0, **kwargs)
    if endpoint.scheme == "udpin":  # pymavlink's learns every address that sends a datagram, and answers all
        conn = BoundedUdpServer(endpoint.address, **kwargs)
    elif endpoint.scheme == "udpout":
        conn = UdpClient(endpoint.address, input=False, **kwargs)
    else:
        conn = mavutil.mavlink_connection(f"{endpoint.scheme}:{endpoint.address}", **kwargs)
    if endpoint.is_udp:
        kept = ask_receive_buffer(conn.port, _UDP_RCVBUF)
        log.debug("%s: UDP receive buffer %d KB", name, kept // 1024)
    return conn


class UdpClient(mavutil.mavudp):
    """pymavlink's ``udpout:``, remembering the address each datagram came from (``last_peer``): anyone may send to
    its port, and whoever reads the messages may want to know which came from where."""

    last_peer: tuple[str, int] | None = None

    def recv(self, n=None) -> bytes:
        try:
            data, self.last_peer = self.port.recvfrom(mavutil.UDP_MAX_PACKET_LEN)
        except OSError as err:
            if err.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b""
            raise
        return data


def ask_receive_buffer(sock: socket.socket, nbytes: int) -> int:
    """Ask for ``nbytes`` of receive buffer on a UDP socket, room for a burst while its reader is descheduled;
    the bytes the kernel keeps (it caps the request at net.core.rmem_max; a smaller buffer still works)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, nbytes)
    except OSError:
        pass  # the kernel's default then; a smaller buffer only drops sooner under a burst
    granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    return granted // 2 if sys.platform == "linux" else granted  # Linux reports twice what it keeps


def has_peer(endpoint: Endpoint, conn: mavutil.mavfile) -> bool:
    """Whether ``conn`` has someone to write to: a UDP server once a client spoke, a TCP link while connected."""
    if endpoint.scheme == "udpin":
        return bool(conn.clients)
    if endpoint.is_tcp:
        return conn.port is not None
    return True
