"""The vehicle gets a wheel, not a checkout: build one, install it in a fresh venv, stage the service, run the demo.

The venv reuses the running Python's packages (torch and the rest), but the project itself comes only from the
wheel: the test checks that ``companion`` imports from the venv, and runs everything outside the repository with
PYTHONPATH cleared. Under the system Python that is ``--system-site-packages``; under a venv (the README's
``python3 -m venv`` route) that flag would reach the base interpreter's site, which has none of the dependencies,
so the child venv gets a .pth file naming the running venv's site-packages instead.
"""

from __future__ import annotations

import configparser
import json
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO


def _run(args: list[str], *, cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def make_venv(venv: Path, *, cwd: Path, env: dict) -> Path:
    """A venv that sees the running interpreter's packages (not the project: it is installed from the wheel)."""
    in_venv = sys.prefix != sys.base_prefix
    flags = [] if in_venv else ["--system-site-packages"]
    made = _run([sys.executable, "-m", "venv", *flags, "--without-pip", str(venv)], cwd=cwd, env=env, timeout=120)
    assert made.returncode == 0, made.stderr
    if in_venv:
        # plain directory lines: the parent's own .pth files (its editable install of the project) are not run
        (child_site,) = (venv / "lib").glob("python*/site-packages")
        (child_site / "parent_venv.pth").write_text("".join(f"{d}\n" for d in site.getsitepackages()))
    return venv


@pytest.mark.slow
def test_wheel_installs_the_service_and_runs_the_demo(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    # build from a copy of what a clone holds: an in-tree build/ of an earlier run could carry stale modules
    src = tmp_path / "src"
    junk = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "*.pyc")
    for name in ("companion", "vehicle", "config", "systemd"):
        shutil.copytree(REPO / name, src / name, symlinks=True, ignore=junk)
    for name in ("pyproject.toml", "README.md"):
        shutil.copyfile(REPO / name, src / name)
    wheels = tmp_path / "wheels"
    built = _run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "-q",
                  "-w", str(wheels)], cwd=tmp_path, env=env, timeout=180)
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = wheels.glob("merlion_companion-*.whl")
    venv = make_venv(tmp_path / "venv", cwd=tmp_path, env=env)
    python, merlion = venv / "bin" / "python", venv / "bin" / "merlion"
    # the system's pip installs into the venv (no copy of pip needed); --no-index: dependencies come from the
    # system site, nothing is downloaded
    installed = _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-index", "-q",
                      str(wheel)], cwd=tmp_path, env=env, timeout=180)
    assert installed.returncode == 0, installed.stdout + installed.stderr
    where = _run([str(python), "-c", "import companion; print(companion.__file__)"], cwd=tmp_path, env=env,
                 timeout=60)
    assert where.stdout.strip().startswith(str(venv)), where.stdout + where.stderr

    root = tmp_path / "stage"
    staged = _run([str(merlion), "install-service", "--root", str(root), "--no-enable"], cwd=tmp_path, env=env,
                  timeout=60)
    assert staged.returncode == 0, staged.stdout + staged.stderr
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str
    unit.read_string((root / "etc/systemd/system/merlion-companion.service").read_text())
    assert unit["Service"]["ExecStart"] == f"{merlion} run --config /etc/merlion/companion.yaml"
    assert unit["Service"]["Type"] == "notify"
    assert (root / "etc/merlion/companion.yaml").read_text() == (REPO / "config/bluerov2-orin.yaml").read_text()

    out = tmp_path / "demo"
    demo = _run([str(merlion), "demo", "--duration", "3", "--out", str(out), "--source",
                 "synthetic://dive?seconds=2", "--tau-ss", "0.1", "--encoder", "visual"], cwd=tmp_path,
                env=dict(env, PATH=f"{venv / 'bin'}:{env.get('PATH', '')}"), timeout=240)
    assert demo.returncode == 0, demo.stdout + demo.stderr
    assert "merlion demo: done" in demo.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["frames_seen"] > 0
    page = (out / "surface" / "index.html")
    assert page.is_file() and "MERLION" in page.read_text()  # the web assets came with the wheel
