"""`merlion surface --web 0` as a real subprocess, and a companion Downlink feeding it over loopback UDP: the
set-up every page test starts from."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from companion.config import MavlinkConfig, SurfaceConfig
from tests.conftest import REPO, stop_process
from vehicle.camera.downlink import Downlink
from vehicle.link.connection import MavLink


@dataclass
class SurfacePage:
    proc: subprocess.Popen
    url: str
    """The page's URL as the tool printed it, token included."""
    web: int
    """The page's port."""
    token: str


def page_state(port: int) -> dict:
    """What the page polls: the tool's /api/state."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/state", timeout=5) as r:
        return json.load(r)


@contextmanager
def surface_with_page(out: Path, port: int, *options: str, duration: float = 90) -> Iterator[SurfacePage]:
    """The tool listening on ``port`` with its gallery in ``out`` and its page on a free port; stopped (if the
    test did not stop it) on the way out."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion", "surface", "--connect", f"udpin:127.0.0.1:{port}", "--out", str(out),
         "--web", "0", *options, "--duration", f"{duration:g}"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
    )
    try:
        line = proc.stdout.readline()
        match = re.search(r"live page at (http://127\.0\.0\.1:(\d+)/\?token=(\S+))", line)
        assert match, line + proc.stderr.read() if proc.poll() is not None else line
        yield SurfacePage(proc, match.group(1), int(match.group(2)), match.group(3))
    finally:
        stop_process(proc, 30)


@contextmanager
def companion_downlink(port: int, cfg: SurfaceConfig, *, start: bool = True, **kwargs) -> Iterator[Downlink]:
    """The companion's side (system 1, component 100): its MAVLink link and Downlink towards the tool on
    ``port``; ``start=False`` leaves starting the Downlink to the caller (after it registered callbacks)."""
    link = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100), name="companion")
    link.start()
    surface = None
    try:
        surface = Downlink(link, cfg, **kwargs)
        if start:
            surface.start()
        yield surface
    finally:
        if surface is not None:
            surface.stop()
        link.stop()
