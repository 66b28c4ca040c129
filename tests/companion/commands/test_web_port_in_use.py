"""A page port someone else holds: `merlion surface --web PORT` and `merlion demo --web PORT` stop at start with one
line naming the port (exit 2), never a traceback, a half-started tool or a demo that runs without its page."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.errors import UsageError
from companion.topside.web import WebServer
from tests.conftest import free_tcp_port, free_udp_port, run_merlion


@pytest.fixture
def held_port() -> Iterator[int]:
    port = free_tcp_port()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as holder:
        holder.bind(("127.0.0.1", port))
        holder.listen()
        yield port


def _one_error(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("merlion: error: "), stderr
    return lines[0]


def test_the_web_server_on_a_port_in_use_is_one_usage_error(tmp_path: Path, held_port: int) -> None:
    # the server itself (a port taken between the command's check and the bind): no AttributeError from its close
    with pytest.raises(UsageError, match=rf"^--web {held_port}: port in use \(127\.0\.0\.1:{held_port}\)"):
        WebServer(dict, tmp_path, held_port)


def test_surface_with_its_page_port_in_use_stops_at_start(tmp_path: Path, held_port: int) -> None:
    out = tmp_path / "gallery"
    done = run_merlion("surface", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", "--out", str(out),
                       "--web", str(held_port), "--duration", "3", timeout=60)
    assert done.returncode == 2, done.stderr
    assert _one_error(done.stderr).startswith(f"merlion: error: --web {held_port}: port in use")
    assert "listening on" not in done.stdout and not out.exists()


def test_demo_with_its_page_port_in_use_stops_at_start(tmp_path: Path, held_port: int) -> None:
    out = tmp_path / "demo"
    done = run_merlion("demo", "--out", str(out), "--web", str(held_port), "--duration", "5", timeout=60)
    assert done.returncode == 2, done.stdout + done.stderr
    assert _one_error(done.stderr).startswith(f"merlion: error: --web {held_port}: port in use")
    assert "surface page at" not in done.stdout and not out.exists()
