"""CORS for origins the operator names (Cockpit served over HTTP from the topside running our HTTP actions): a real
`merlion extension` process, real HTTP requests carrying Origin headers. Off by default, where only the vehicle's
own pages may change anything (``vehicle_guard``), without any secret."""

from __future__ import annotations

import http.client
import json
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.companion.live_harness import write_config
from tests.conftest import REPO, run_merlion, stop_process

COCKPIT = "http://cockpit.example:8080"
"""Allowed by the configuration (extension.allowed_origins)."""
APP = "app://cockpit"
"""Allowed by the command line (--allow-origin)."""
EVIL = "http://evil.example"


@contextmanager
def _extension(tmp_path: Path, *args: str, **sections) -> Iterator[int]:
    """`merlion extension --no-companion` on a free port: its port."""
    cfg = write_config(tmp_path / "merlion.yaml", **sections)
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion", "extension", "--data", str(tmp_path / "data"), "--port", "0",
         "--host", "127.0.0.1", "--config", str(cfg), "--no-companion", "--duration", "120", *args],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()
        match = re.search(r"page at http://127\.0\.0\.1:(\d+)/", line)
        assert match, f"no page line: {line!r} (exit {proc.poll()})"
        yield int(match.group(1))
    finally:
        stop_process(proc, 30)


def _request(port: int, method: str, path: str, headers: dict | None = None,
             body: dict | None = None) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        data = None if body is None else json.dumps(body).encode()
        sent = {**({"Content-Type": "application/json"} if data is not None else {}), **(headers or {})}
        conn.request(method, path, body=data, headers=sent)
        answer = conn.getresponse()
        return answer.status, {k.lower(): v for k, v in answer.getheaders()}, answer.read()
    finally:
        conn.close()


def _preflight(port: int, origin: str, method: str = "POST") -> tuple[int, dict[str, str], bytes]:
    return _request(port, "OPTIONS", "/api/companion", {
        "Origin": origin, "Access-Control-Request-Method": method,
        "Access-Control-Request-Headers": "content-type,x-merlion-token",
        "Access-Control-Request-Private-Network": "true", "Sec-Fetch-Mode": "cors", "Sec-Fetch-Site": "cross-site"})


def _cross_site(origin: str) -> dict[str, str]:
    """What a browser sends with a fetch from a page of ``origin``."""
    return {"Origin": origin, "Sec-Fetch-Mode": "cors", "Sec-Fetch-Site": "cross-site", "Referer": f"{origin}/"}


def test_the_allowed_origins_get_preflight_actions_and_json_and_no_other_origin_does(tmp_path) -> None:
    with _extension(tmp_path, "--allow-origin", APP, extension={"allowed_origins": ["HTTP://Cockpit.example:8080/"]}) \
            as port:
        for origin in (COCKPIT, APP):
            status, headers, body = _preflight(port, origin)
            assert status == 204 and body == b"", origin
            assert headers["access-control-allow-origin"] == origin and headers["vary"] == "Origin"
            assert set(headers["access-control-allow-methods"].split(", ")) == {"GET", "POST"}
            assert "x-merlion-token" in headers["access-control-allow-headers"].lower()
            assert headers["access-control-allow-private-network"] == "true"
            status, headers, body = _request(port, "POST", "/api/companion", _cross_site(origin), {"run": False})
            assert status == 200 and json.loads(body) == {"companion_running": False}
            assert headers["access-control-allow-origin"] == origin
            status, headers, body = _request(port, "GET", "/api/extension", _cross_site(origin))
            assert status == 200 and json.loads(body)["supervised"] is True
            assert headers["access-control-allow-origin"] == origin
        assert _preflight(port, COCKPIT, method="DELETE")[0] == 403

        for origin in (EVIL, "null", "http://cockpit.example:8081", "https://cockpit.example:8080"):
            status, headers, _ = _preflight(port, origin)
            assert status == 403 and "access-control-allow-origin" not in headers, origin
            status, headers, _ = _request(port, "POST", "/api/companion", _cross_site(origin), {"run": False})
            assert status == 403 and "access-control-allow-origin" not in headers, origin
            status, headers, _ = _request(port, "GET", "/api/extension", _cross_site(origin))
            assert status == 403 and "access-control-allow-origin" not in headers, origin


def test_by_default_no_origin_gets_cors_and_everything_answers_as_before(tmp_path) -> None:
    with _extension(tmp_path) as port:
        status, headers, _ = _preflight(port, COCKPIT)
        assert status == 501  # http.server's answer to a method it does not serve: there is no OPTIONS
        for origin in (COCKPIT, EVIL):
            status, headers, body = _request(port, "POST", "/api/companion", _cross_site(origin), {"run": False})
            assert status == 403 and json.loads(body)["error"] == f"cross-origin request from {origin!r}"
            assert status == 403 and _request(port, "GET", "/api/extension", _cross_site(origin))[0] == 403
        same = {"Origin": f"http://127.0.0.1:{port}"}  # a page the vehicle serves: no secret needed
        status, headers, body = _request(port, "POST", "/api/companion", same, {"run": False})
        assert status == 200 and json.loads(body) == {"companion_running": False}
        assert not [h for h in headers if h.startswith("access-control-") or h == "vary"]


@pytest.mark.parametrize(("args", "config", "named"), [
    (("--allow-origin", "null"), None, "--allow-origin 'null' is not a web origin"),
    ((), ["*"], "extension.allowed_origins"),
])
def test_an_origin_that_is_not_one_is_a_one_line_error(tmp_path, args, config, named) -> None:
    cfg = write_config(tmp_path / "merlion.yaml", **({"extension": {"allowed_origins": config}} if config else {}))
    done = run_merlion("extension", "--data", str(tmp_path / "d"), "--config", str(cfg), "--no-companion",
                       "--duration", "1", *args, timeout=60)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert done.stderr.startswith("merlion: error: ") and named in done.stderr
