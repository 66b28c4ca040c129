"""A demo killed with SIGKILL takes its simulator and surface tool with it (real processes, nothing mocked)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from companion.live import die_with_parent
from tests.conftest import REPO

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")


def _children_up(proc: subprocess.Popen, timeout: float = 120.0) -> list[psutil.Process]:
    """The demo's two children (simulator, surface tool), once both run the merlion command itself."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        kids = psutil.Process(proc.pid).children()
        try:
            if len(kids) == 2 and all("die_with_parent" not in " ".join(k.cmdline()) for k in kids):
                return kids  # exec'd: each is now the real command
        except psutil.NoSuchProcess:
            pass
        time.sleep(0.1)
    raise AssertionError(f"the demo's children did not start (demo exit {proc.poll()})")


def test_sigkill_of_the_demo_ends_its_children(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "companion", "demo", "--duration", "600", "--out",
                             str(tmp_path / "demo"), "--encoder", "visual"], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kids: list[psutil.Process] = []
    try:
        kids = _children_up(proc)
        names = sorted(k.cmdline()[3] for k in kids)  # python -m companion <subcommand>
        assert names == ["sim-vehicle", "surface"], [k.cmdline() for k in kids]
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        gone, alive = psutil.wait_procs(kids, timeout=10)
        assert not alive, [k.cmdline() for k in alive]
    finally:
        if proc.poll() is None:
            proc.kill()
        for kid in kids:  # only if the test failed: never leave them running
            if kid.is_running():
                kid.kill()


def test_a_child_whose_parent_is_already_gone_does_not_start(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    line = die_with_parent.command([sys.executable, "-c", f"open({str(marker)!r}, 'w')"], parent=1)
    done = subprocess.run(line, cwd=REPO, timeout=60)
    assert done.returncode == 1 and not marker.exists()
    line = die_with_parent.command([sys.executable, "-c", f"open({str(marker)!r}, 'w')"])
    assert subprocess.run(line, cwd=REPO, timeout=60).returncode == 0 and marker.exists()
