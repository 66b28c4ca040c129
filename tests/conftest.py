"""Shared test fixtures: the real data in ../shared/data, free loopback ports, the merlion command."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("MERLION_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_file(relative: str) -> Path:
    """A file under ../shared/data, or skip the test cleanly when the data is not there."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared test data absent: {path}")
    return path


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data absent: {SHARED_DATA}")
    return SHARED_DATA


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 the OS says is free now (never a fixed port)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(proc: subprocess.Popen, grace_s: float) -> None:
    """SIGTERM, and SIGKILL if it has not ended within ``grace_s``: what a test's clean-up owes a child."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_merlion(*args: str, timeout: float = 240, cwd: Path | None = None, env: dict | None = None,
                input: str | None = None) -> subprocess.CompletedProcess:
    """The real ``merlion`` command in a subprocess, as a user would run it."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    return subprocess.run(
        [sys.executable, "-m", "companion", *args],
        capture_output=True, text=True, timeout=timeout, cwd=cwd or REPO, env=full_env, input=input,
    )
