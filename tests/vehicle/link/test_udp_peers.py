"""A ``udpin:`` link answers at most 16 peers, and a flood of new source addresses cannot push out one that speaks:
real UDP sockets on 127.0.0.1, real pymavlink heartbeats."""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.link.connection import MavLink
from vehicle.link.endpoint import open_transport, parse_connection
from vehicle.link.udp_peers import MAX_PEERS, BoundedUdpServer


def _sockets(n: int) -> list[socket.socket]:
    out = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.5)
        out.append(s)
    return out


def _heartbeat(system: int) -> bytes:
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3).pack(
        mav.MAVLink(None, srcSystem=system, srcComponent=190))


def _read_all(conn, count: int) -> None:
    for _ in range(count):
        assert conn.select(2.0)
        assert conn.recv()


def _got(sock: socket.socket) -> bool:
    """Whether a datagram waits (on loopback a datagram is queued at the receiver before ``sendto`` returns)."""
    sock.setblocking(False)
    try:
        return bool(sock.recv(4096))
    except BlockingIOError:
        return False


def _statustext(sock: socket.socket) -> bool:
    parser = mav.MAVLink(None)
    for _ in range(20):  # the link's own heartbeats come too
        try:
            data = sock.recv(4096)
        except TimeoutError:
            continue
        if any(m.get_type() == "STATUSTEXT" for m in parser.parse_buffer(data) or []):
            return True
    return False


def test_a_udp_server_answers_16_peers_and_keeps_the_ones_that_speak():
    port = free_udp_port()
    conn = open_transport(parse_connection(f"udpin:127.0.0.1:{port}"), 1, 100, "test")
    station, strangers = _sockets(1)[0], _sockets(40)
    try:
        assert isinstance(conn, BoundedUdpServer)
        station.sendto(_heartbeat(255), ("127.0.0.1", port))
        for i, s in enumerate(strangers):  # one datagram from each of 40 ports: before, 41 peers were answered
            s.sendto(_heartbeat(100 + i), ("127.0.0.1", port))
        _read_all(conn, 41)
        assert len(conn.clients) == MAX_PEERS == 16 and station.getsockname() in conn.clients
        assert conn.refused_peers == 41 - MAX_PEERS
        conn.write(b"hello")
        assert _got(station)
        assert sum(_got(s) for s in strangers) == MAX_PEERS - 1  # the first 15 strangers; the rest are not answered
    finally:
        for s in (station, *strangers):
            s.close()
        conn.close()


def test_a_peer_silent_for_10_s_gives_its_place_to_a_new_one():
    now = [0.0]
    port = free_udp_port()
    conn = BoundedUdpServer(f"127.0.0.1:{port}", source_system=1, source_component=100, max_peers=2,
                            clock=lambda: now[0])
    old, station, newcomer = _sockets(3)
    try:
        old.sendto(_heartbeat(1), ("127.0.0.1", port))
        station.sendto(_heartbeat(2), ("127.0.0.1", port))
        _read_all(conn, 2)
        now[0] = 9.9
        station.sendto(_heartbeat(2), ("127.0.0.1", port))  # the station speaks; the old peer does not
        newcomer.sendto(_heartbeat(3), ("127.0.0.1", port))
        _read_all(conn, 2)
        assert newcomer.getsockname() not in conn.clients  # the old peer is silent, but not for 10 s yet
        now[0] = 10.0
        newcomer.sendto(_heartbeat(3), ("127.0.0.1", port))
        _read_all(conn, 1)
        assert conn.clients == {station.getsockname(), newcomer.getsockname()}
    finally:
        for s in (old, station, newcomer):
            s.close()
        conn.close()


def test_the_link_keeps_talking_to_its_ground_station_through_a_flood_of_new_addresses():
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100))
    link.start()
    station, strangers = _sockets(1)[0], _sockets(100)
    try:
        assert link.wait_open(5)
        station.sendto(_heartbeat(255), ("127.0.0.1", port))
        assert wait_until(lambda: link.rx_messages == 1, 5)
        for i, s in enumerate(strangers):
            s.sendto(_heartbeat(100 + i % 50), ("127.0.0.1", port))
        assert wait_until(lambda: link.rx_messages == 101, 5)
        assert link.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"still here")) > 0
        assert _statustext(station)
        assert len(link._conn.clients) == MAX_PEERS
    finally:
        link.stop()
        for s in (station, *strangers):
            s.close()
