"""Connection strings are checked before any thread starts, and a UDP server has room for a burst."""

from __future__ import annotations

import socket

import pytest

from companion.errors import UsageError
from tests.conftest import free_udp_port
from vehicle.link.endpoint import has_peer, open_transport, parse_connection


def test_connection_strings_are_checked_up_front():
    assert parse_connection("udpin:0.0.0.0:14550").scheme == "udpin"
    assert str(parse_connection("tcp:127.0.0.1:5777")) == "tcp:127.0.0.1:5777"
    serial = parse_connection("/dev/ttyACM0,57600")
    assert (serial.scheme, serial.address, serial.baud) == ("serial", "/dev/ttyACM0", 57600)
    assert serial.reconnects and parse_connection("tcp:h:1").reconnects and not parse_connection("udpin:h:1").reconnects
    for bad in ("udp-in:1.2.3.4:5", "udpin:127.0.0.1", "tcp:host:99999", "", "/dev/ttyACM0,fast"):
        with pytest.raises(UsageError, match="mavlink connection"):
            parse_connection(bad)


def test_a_udp_server_has_a_peer_only_once_a_client_spoke_and_asks_for_a_large_receive_buffer():
    port = free_udp_port()
    endpoint = parse_connection(f"udpin:127.0.0.1:{port}")
    conn = open_transport(endpoint, 1, 100, "test")
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert not has_peer(endpoint, conn)
        # the kernel doubles what it grants and caps it at net.core.rmem_max; the default is about 208 KB
        with open("/proc/sys/net/core/rmem_max") as f:
            cap = int(f.read())
        granted = conn.port.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert granted >= min(1 << 20, cap)
        client.sendto(b"\xfd", ("127.0.0.1", port))
        assert conn.select(2.0)
        conn.recv()
        assert has_peer(endpoint, conn)
    finally:
        client.close()
        conn.close()
