"""Shared test fixtures: the real data in ../shared/data, free loopback ports, the merlion command."""

from __future__ import annotations

import itertools
import os
import random
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from companion.vision.encoders.cpu_threads import usable_cores

if TYPE_CHECKING:
    from xdist.workermanage import WorkerController

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


PORT_BLOCK = 1000
"""Ports each pytest process (each xdist worker) takes its loopback ports from, in a block of its own."""
_PORT_BASE = 20000
"""Below Linux's ephemeral range (32768-60999 by default): the OS never hands these out on its own, so a port
picked here and bound a moment later by a child cannot meanwhile become another socket's source port."""
_ports: Iterator[int] | None = None


def _worker_ports() -> Iterator[int]:
    """This process's ports, in turn: a block per xdist worker (gw0, gw1, ...) so that two workers never pick the
    same port, starting at a random place in it so that a second test run beside this one rarely shares a
    port either; a port is handed out again only after the whole block went round."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    low = _PORT_BASE + (index % ((32768 - _PORT_BASE) // PORT_BLOCK)) * PORT_BLOCK
    start = random.randrange(PORT_BLOCK)
    return itertools.cycle([low + (start + i) % PORT_BLOCK for i in range(PORT_BLOCK)])


def _free_port(kind: socket.SocketKind) -> int:
    global _ports
    if _ports is None:
        _ports = _worker_ports()
    for _ in range(PORT_BLOCK):
        port = next(_ports)
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:  # something outside the tests holds it
                continue
            return port
    raise RuntimeError(f"no free loopback port in this worker's block of {PORT_BLOCK}")


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that is free now and that no other test (in this process or another xdist
    worker) is handed until this block of ports went round (never a fixed port)."""
    return _free_port(socket.SOCK_DGRAM)


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1, picked as free_udp_port picks one."""
    return _free_port(socket.SOCK_STREAM)


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



def pytest_configure(config: pytest.Config) -> None:
    """Under xdist, each worker gets its share of the cores for torch and BLAS (``OMP_NUM_THREADS``, read by
    ``torch_runtime.configure_threads``; the BLAS variables by numpy at import). Two workers each running one
    thread per core put four busy threads on two cores, and the encoding and ridge fits of the fish-head tests
    then thrash. Set here, on the controller, before the workers start, so they and the commands they run inherit
    it; a value already set by the caller is kept."""
    workers = getattr(config.option, "numprocesses", None)
    most = getattr(config.option, "maxprocesses", None)
    if isinstance(workers, int) and isinstance(most, int) and most > 0:
        workers = min(workers, most)
    if os.environ.get("PYTEST_XDIST_WORKER") or not isinstance(workers, int) or workers < 2:
        return
    share = str(max(1, usable_cores() // workers))
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, share)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under xdist (pyproject's ``-n 2 --dist loadgroup``) a module runs whole on one worker, so its
    module-scoped fixtures (an encoder, 803 encoded frames, a Ray cluster) are built once, not once per worker; a
    test marked ``xdist_group(NAME)`` runs with the other tests of that group instead (tests that must not run side
    by side with each other)."""
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node: WorkerController, ids: list[str]) -> None:
    """Stops the run when xdist could not group the tests: without the ``@group`` suffix xdist adds to each nodeid,
    loadgroup sends every test on its own, so a module's tests run on both workers at once (its module fixtures
    built twice; the extension's stop test stopped a companion still importing torch). pytest 9.2 made nodeids
    read-only to xdist 3.8 that way (pyproject caps pytest below 9.2)."""
    if node.config.getoption("dist") == "loadgroup" and ids and "@" not in ids[0]:
        pytest.exit(f"pytest-xdist's loadgroup did not group the tests under pytest {pytest.__version__} ({ids[0]} "
                    f"has no @group): pip install 'pytest<9.2', or run with -n 0", returncode=4)
