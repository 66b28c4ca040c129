"""The live page of a real `merlion surface` process against hostile web clients: another origin's page in a real
Chromium cannot read the state, a rebinding Host is refused, 300 slow bodies do not pin 300 threads, and a 6 kB
path, an oversized head or a bad Content-Length get a clean 4xx (no traceback)."""

from __future__ import annotations

import http.client
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from companion.topside.http_bounds import MAX_THREADS
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.companion.topside.live_page import surface_with_page
from tests.conftest import free_udp_port
from tests.waiting import wait_until


def _request(port: int, method: str, path: str, *, host: str | None = None, headers: dict | None = None,
             body: bytes = b"", length: str | None = None) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=15)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", host or f"127.0.0.1:{port}")
        for name, value in (headers or {}).items():
            conn.putheader(name, value)
        conn.putheader("Content-Length", length if length is not None else str(len(body)))
        conn.endheaders(body)
        reply = conn.getresponse()
        return reply.status, reply.read()
    finally:
        conn.close()


def _threads(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Threads:"):
            return int(line.split()[1])
    raise AssertionError("no Threads line")


@pytest.fixture
def surface(tmp_path):
    with surface_with_page(tmp_path / "gallery", free_udp_port(), "--web-allow-host", "proxy.example",
                           duration=120) as shown:
        yield shown
    stderr = shown.proc.stderr.read()
    assert "Traceback" not in stderr, stderr


def test_another_origin_in_a_real_browser_reads_no_state(surface):
    chromium_or_skip()
    port = surface.web
    evil = (f'<html><body><script src="http://127.0.0.1:{port}/state.js"></script><script>'
            f'window.STOLEN = window.MERLION_STATE ? JSON.stringify(window.MERLION_STATE).length : 0;'
            f'window.DONE = true;</script></body></html>').encode()

    class Evil(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(evil)))
            self.end_headers()
            self.wfile.write(evil)

        def log_message(self, *args) -> None:
            pass

    other = ThreadingHTTPServer(("127.0.0.1", 0), Evil)
    threading.Thread(target=other.serve_forever, daemon=True).start()
    try:
        for origin in (f"http://127.0.0.1:{other.server_address[1]}/", f"http://localhost:{other.server_address[1]}/"):
            with Page(origin) as page:
                assert page.wait_for("window.DONE === true", 30)
                assert page.evaluate("window.STOLEN") == 0, origin
        with Page(surface.url) as page:  # the page itself still gets its state
            assert page.wait_for("typeof window.MERLION_STATE === 'object' && window.MERLION_STATE !== null", 30)
    finally:
        other.shutdown()
        other.server_close()


def test_state_only_for_this_server_and_the_same_origin(surface):
    port = surface.web
    assert _request(port, "GET", "/api/state")[0] == 200  # a plain client (no browser headers)
    assert _request(port, "GET", "/api/state", host=f"localhost:{port}")[0] == 200
    assert _request(port, "GET", "/api/state", host="proxy.example")[0] == 200  # --web-allow-host
    assert _request(port, "GET", "/api/state", host=f"evil.example:{port}")[0] == 403  # DNS rebinding
    assert _request(port, "GET", "/state.js", host="127.0.0.1:1")[0] == 403  # another port's name
    for headers in ({"Origin": "http://evil.example"}, {"Sec-Fetch-Site": "cross-site"},
                    {"Sec-Fetch-Site": "same-site"}, {"Referer": "http://127.0.0.1:1/x.html"}):
        for path in ("/state.js", "/api/state", "/files/gallery.json"):
            status, body = _request(port, "GET", path, headers=headers)
            assert status == 403 and b"summary" not in body, (path, headers)
    same = {"Origin": f"http://127.0.0.1:{port}", "Sec-Fetch-Site": "same-origin"}
    assert _request(port, "GET", "/api/state", headers=same)[0] == 200
    # the state as a script runs in the page that includes it: naming no page is no proof of being ours (over plain
    # HTTP a stranger's <script referrerpolicy="no-referrer"> sends no Origin, Referer or Sec-Fetch-Site)
    status, body = _request(port, "GET", "/state.js")
    assert status == 403 and b"summary" not in body
    for named in ({"Referer": f"http://127.0.0.1:{port}/"}, {"Sec-Fetch-Site": "same-origin"}):
        status, body = _request(port, "GET", "/state.js", headers=named)
        assert status == 200 and body.startswith(b"window.MERLION_STATE = {"), named
    assert _request(port, "GET", "/", headers={"Sec-Fetch-Site": "cross-site"})[0] == 200  # a link to the page


def test_bad_input_is_a_clean_4xx(surface):
    port = surface.web
    token_path = f"/api/mark?token={surface.token}"
    assert _request(port, "GET", "/files/" + "a" * 6000)[0] == 414
    assert _request(port, "GET", "/" + "b" * 6000)[0] == 414
    assert _request(port, "POST", token_path, body=b"{}", length="abc")[0] == 400
    assert _request(port, "POST", token_path, body=b"{}", length="-5")[0] == 400
    assert _request(port, "GET", "/api/state", headers={f"X-Pad-{i}": "p" * 100 for i in range(200)})[0] == 431
    assert _request(port, "GET", "/files/%00bad")[0] == 404
    assert _request(port, "GET", "/api/state")[0] == 200  # and it still serves


@pytest.mark.slow
def test_three_hundred_slow_bodies_do_not_pin_threads(surface):
    port = surface.web
    before = _threads(surface.proc.pid)
    held: list[socket.socket] = []
    try:
        for _ in range(300):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(f"POST /api/mark?token={surface.token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                      f"Content-Length: 1000\r\n\r\n{{\"index\"".encode())
            held.append(s)
        peak = _threads(surface.proc.pid)
        assert peak <= before + MAX_THREADS + 2, (before, peak)
        # the slow ones are cut at their read deadline; the page answers again
        assert wait_until(lambda: _request(port, "GET", "/api/state")[0] == 200, 60)
        assert _threads(surface.proc.pid) <= before + MAX_THREADS + 2
    finally:
        for s in held:
            s.close()


def test_behind_a_proxy_that_rewrites_host_the_forwarded_name_is_the_origin(surface):
    """nginx's default passes Host as the upstream's address and adds X-Forwarded-Host: the page's own origin is
    then the proxy's name, when --web-allow-host names it; any other forwarded name is no excuse."""
    port = surface.web
    proxied = {"X-Forwarded-Host": "proxy.example", "Origin": "https://proxy.example",
               "Sec-Fetch-Site": "same-origin"}
    assert _request(port, "GET", "/api/state", headers=proxied)[0] == 200
    status, _ = _request(port, "POST", f"/api/mark?token={surface.token}", headers=proxied,
                         body=b'{"index": 1, "kind": "like"}')
    assert status == 400  # past the guard: the mark itself fails (no companion), not the origin
    forged = dict(proxied, **{"X-Forwarded-Host": "evil.example", "Origin": "https://evil.example"})
    assert _request(port, "GET", "/api/state", headers=forged)[0] == 403
    assert _request(port, "POST", f"/api/mark?token={surface.token}", headers=forged, body=b"{}")[0] == 403
