"""The live page's guard: loopback only by default, and no change without the per-run token from the same origin."""

from __future__ import annotations

import http.client
import json
import re
import socket
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from companion.topside.web import TOKEN_HEADER, WebServer
from tests.conftest import REPO, free_udp_port


def _request(port: int, method: str, path: str, *, host: str = "127.0.0.1", headers: dict | None = None,
             body: bytes | None = None, address: str = "127.0.0.1") -> tuple[int, bytes]:
    conn = http.client.HTTPConnection(address, port, timeout=5)
    try:
        conn.putrequest(method, path, skip_host=True)
        conn.putheader("Host", f"{host}:{port}")
        for name, value in (headers or {}).items():
            conn.putheader(name, value)
        conn.putheader("Content-Length", str(len(body or b"")))
        conn.endheaders(body)
        reply = conn.getresponse()
        return reply.status, reply.read()
    finally:
        conn.close()


@pytest.fixture
def page(tmp_path: Path):
    marks: list[dict] = []

    def mark(body: dict) -> dict:
        marks.append(body)
        return {"marked": body.get("image_index")}

    web = WebServer(lambda: {"frames": []}, tmp_path, 0, actions={"mark": mark})
    web.start()
    yield web, marks
    web.close()


def test_reads_stay_simple_and_changes_need_the_token(page) -> None:
    web, marks = page
    assert _request(web.port, "GET", "/api/state")[0] == 200  # no token for a read
    body = json.dumps({"image_index": 3}).encode()
    status, reply = _request(web.port, "POST", "/api/mark", body=body)
    assert status == 403 and b"token" in reply
    assert _request(web.port, "POST", "/api/mark?token=wrong", body=body)[0] == 403
    assert marks == []
    status, reply = _request(web.port, "POST", f"/api/mark?token={web.token}", body=body)
    assert (status, json.loads(reply)) == (200, {"marked": 3})
    status, _ = _request(web.port, "POST", "/api/mark", body=body, headers={TOKEN_HEADER: web.token})
    assert status == 200 and len(marks) == 2


def test_cross_origin_and_rebound_names_are_refused_even_with_the_token(page) -> None:
    web, marks = page
    path = f"/api/mark?token={web.token}"
    body = b"{}"
    assert _request(web.port, "POST", path, body=body, headers={"Origin": "http://evil.example"})[0] == 403
    assert _request(web.port, "POST", path, body=body, headers={"Sec-Fetch-Site": "cross-site"})[0] == 403
    assert _request(web.port, "POST", path, body=body, host="evil.example")[0] == 403  # DNS rebinding
    assert marks == []
    same = {"Origin": f"http://127.0.0.1:{web.port}", "Sec-Fetch-Site": "same-origin"}
    assert _request(web.port, "POST", path, body=body, headers=same)[0] == 200
    assert _request(web.port, "GET", f"/api/mark?token={web.token}")[0] == 404  # a GET never changes anything


def test_the_surface_page_listens_on_loopback_only_and_prints_its_token(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion", "surface", "--connect", f"udpin:127.0.0.1:{free_udp_port()}",
         "--out", str(tmp_path / "gallery"), "--web", "0", "--duration", "30"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = ""
        for line in proc.stdout:
            if "live page at" in line:
                break
        match = re.search(r"live page at (http://127\.0\.0\.1:(\d+)/\?token=(\S+))", line)
        assert match, line
        url, port, token = match.group(1), int(match.group(2)), match.group(3)
        assert urlsplit(url).query == f"token={token}"
        assert _request(port, "GET", "/api/state")[0] == 200
        # bound to 127.0.0.1: another address of this machine (127.0.0.2 on lo, and a real interface if any)
        others = ["127.0.0.2"] + [a for a in _own_addresses() if not a.startswith("127.")]
        for address in others:
            with pytest.raises(OSError):
                _request(port, "GET", "/api/state", address=address)
        assert _request(port, "POST", "/api/mark", body=b"{}")[0] == 403  # no token: refused
    finally:
        proc.terminate()
        proc.communicate(timeout=30)


def _own_addresses() -> list[str]:
    try:
        return sorted({info[4][0] for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)})
    except OSError:
        return []
