"""The systemd unit: the keys the vehicle relies on, staged by `merlion install-service`, and `systemd-analyze verify`."""

from __future__ import annotations

import configparser
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import REPO, run_merlion

UNIT = REPO / "systemd" / "merlion-companion.service"


def parse(text: str) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read_string(text)
    return parser


def test_unit_has_notify_watchdog_restart_network_and_a_dedicated_user() -> None:
    unit = parse(UNIT.read_text())
    assert unit["Service"]["Type"] == "notify"
    assert int(unit["Service"]["WatchdogSec"]) > 0
    assert unit["Service"]["Restart"] == "on-failure"
    assert "network-online.target" in unit["Unit"]["After"] and "network-online.target" in unit["Unit"]["Wants"]
    assert unit["Service"]["User"] not in ("", "root")
    assert "--config /etc/merlion/companion.yaml" in unit["Service"]["ExecStart"]


def test_install_service_stages_unit_and_config_and_the_unit_verifies(tmp_path: Path) -> None:
    done = run_merlion("install-service", "--root", str(tmp_path), "--user", "merlion", timeout=60)
    assert done.returncode == 0, done.stderr
    unit_path = tmp_path / "etc" / "systemd" / "system" / "merlion-companion.service"
    conf = tmp_path / "etc" / "merlion" / "companion.yaml"
    assert unit_path.is_file() and conf.is_file()
    assert conf.read_text() == (REPO / "config" / "bluerov2-orin.yaml").read_text()
    exec_start = parse(unit_path.read_text())["Service"]["ExecStart"]
    program = exec_start.split()[0]
    assert Path(program).exists(), exec_start
    # a second install keeps the operator's edited config
    conf.write_text("sampler:\n  k: 9\n")
    assert run_merlion("install-service", "--root", str(tmp_path), timeout=60).returncode == 0
    assert conf.read_text() == "sampler:\n  k: 9\n"
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed here (apt-get install systemd)")
    verify = subprocess.run(["systemd-analyze", "verify", str(unit_path)], capture_output=True, text=True,
                            timeout=60)
    problems = [line for line in (verify.stdout + verify.stderr).splitlines() if "merlion-companion" in line]
    assert verify.returncode == 0 and not problems, verify.stdout + verify.stderr


def test_install_service_names_a_missing_config(tmp_path: Path) -> None:
    done = run_merlion("install-service", "--root", str(tmp_path), "--config", str(tmp_path / "nope.yaml"), timeout=60)
    assert done.returncode == 2  # a missing input file is bad input
    assert done.stderr.strip().splitlines()[-1] == f"merlion: error: {tmp_path / 'nope.yaml'}: no such config file"


def test_install_service_refuses_a_bad_user_name_and_an_unwritable_root(tmp_path: Path) -> None:
    bad_user = run_merlion("install-service", "--root", str(tmp_path / "a"), "--user", "x\nExecStartPre=/bin/sh",
                           timeout=60)
    assert bad_user.returncode == 2
    assert bad_user.stderr.strip().startswith("merlion: error: --user") and len(bad_user.stderr.splitlines()) == 1
    assert not (tmp_path / "a").exists()
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    unwritable = run_merlion("install-service", "--root", str(blocker), "--no-enable", timeout=60)
    assert unwritable.returncode == 1
    assert unwritable.stderr.startswith(f"merlion: error: {blocker}/") and len(unwritable.stderr.splitlines()) == 1
    assert "Traceback" not in unwritable.stderr
