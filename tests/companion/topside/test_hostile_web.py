"""The live page's server against a hostile web client: real TCP sockets on 127.0.0.x, the real ``WebServer``."""

from __future__ import annotations

import http.client
import json
import socket

import pytest

from companion.topside.http_bounds import MAX_PER_ADDRESS, MAX_THREADS
from companion.topside.web import TOKEN_HEADER, WebServer
from tests.waiting import wait_until


@pytest.fixture
def web(tmp_path):
    server = WebServer(lambda: {"summary": []}, tmp_path, 0, actions={"mark": lambda body: {"got": body}})
    server.start()
    yield server
    server.close()


def _get(port: int, path: str, *, source: str = "127.0.0.1") -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=15, source_address=(source, 0))
    try:
        conn.request("GET", path, headers={"Host": f"127.0.0.1:{port}"})
        reply = conn.getresponse()
        return reply.status, reply.read()
    finally:
        conn.close()


def _post(web: WebServer, body: bytes) -> tuple[int, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", web.port, timeout=15)
    try:
        conn.request("POST", "/api/mark", body=body, headers={
            "Host": f"127.0.0.1:{web.port}", TOKEN_HEADER: web.token, "Content-Type": "application/json"})
        reply = conn.getresponse()
        return reply.status, json.loads(reply.read())
    finally:
        conn.close()


def _slow(port: int, source: str) -> socket.socket:
    """A connection from ``source`` that sends half a request and then nothing: a slow-loris."""
    s = socket.create_connection(("127.0.0.1", port), timeout=15, source_address=(source, 0))
    s.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1")
    return s


def test_one_address_holds_at_most_16_of_the_32_slots_and_the_page_still_answers_others(web):
    """40 connections from one address that send half a request: before, 32 of them held every slot until the
    read deadline and everyone got a 503; now that address holds 16 at most (the rest refused at once, or let in
    in place of one of its own slow ones) and another address is served."""
    slow = []
    try:
        slow = [_slow(web.port, "127.0.0.1") for _ in range(40)]
        server = web._server
        assert wait_until(lambda: server.refused_busy + server.cut_slow == 40 - MAX_PER_ADDRESS, 10)
        assert wait_until(lambda: web.serving() == MAX_PER_ADDRESS < MAX_THREADS, 10)
        status, body = _get(web.port, "/api/state", source="127.0.0.2")  # another machine: served
        assert status == 200 and json.loads(body) == {"summary": []}
    finally:
        for s in slow:
            s.close()
    assert wait_until(lambda: web.serving() == 0, 10)
    assert _get(web.port, "/api/state")[0] == 200  # the address's slots came back


def test_slow_senders_from_two_addresses_do_not_lock_out_a_third(web):
    """16 half-sent requests from each of two addresses fill all 32 slots; before, 0 of 25 probes from a third
    address were answered until the read deadline. Now each probe takes the slot of the oldest slow sender."""
    slow = []
    try:
        slow = [_slow(web.port, source) for source in ("127.0.0.2", "127.0.0.3") for _ in range(MAX_PER_ADDRESS)]
        server = web._server
        assert wait_until(lambda: server.slow_senders() == 2 * MAX_PER_ADDRESS == MAX_THREADS, 20)
        answered = [_get(web.port, "/api/state")[0] for _ in range(25)]
        assert answered == [200] * 25
        assert server.cut_slow >= 1 and server.refused_busy == 0
    finally:
        for s in slow:
            s.close()


def test_deeply_nested_json_is_a_400_not_a_recursion(web):
    status, answer = _post(web, b"[" * 30_000 + b"]" * 30_000)  # within the 64 kB a body may have
    assert (status, answer) == (400, {"error": "JSON nested deeper than 32 levels"})
    status, answer = _post(web, b'{"a": ' * 40 + b"1" + b"}" * 40)
    assert status == 400
    status, answer = _post(web, json.dumps({"index": 3, "kind": "like", "note": "[[[[" * 100}).encode())
    assert status == 200 and answer["got"]["index"] == 3  # brackets inside a string are text
