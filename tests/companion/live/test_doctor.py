"""`merlion doctor` against real sockets: a simulated autopilot found, a missing camera and a bad config reported."""

from __future__ import annotations

from pathlib import Path

import yaml

from tests.conftest import free_udp_port, run_merlion
from vehicle.sim.vehicle import SimVehicle


def test_doctor_finds_the_autopilot_and_reports_a_missing_camera_with_its_fix(tmp_path: Path) -> None:
    port = free_udp_port()
    cfg = tmp_path / "vehicle.yaml"
    cfg.write_text(yaml.safe_dump({
        "source": {"uri": "/dev/video97"},
        "encoder": {"name": "visual"},
        "mavlink": {"connection": f"udpin:127.0.0.1:{port}"},
        "store": {"dir": str(tmp_path / "store")},
    }))
    with SimVehicle(f"udpout:127.0.0.1:{port}"):
        done = run_merlion("doctor", "--config", str(cfg), "--wait", "20", timeout=120)
    assert done.returncode == 1, done.stdout
    lines = done.stdout.splitlines()
    camera = next(i for i, line in enumerate(lines) if "camera" in line)
    assert lines[camera].startswith("FAIL") and "/dev/video97: no such device" in lines[camera]
    assert "fix:" in lines[camera + 1]
    assert any(line.startswith("ok") and "autopilot" in line and "system 1 component 1" in line for line in lines)
    assert any(line.startswith("ok") and "disk" in line for line in lines)
    assert lines[-1] == "merlion doctor: 1 problem(s)"


def test_doctor_on_a_bad_config_names_the_key(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("mavlink:\n  component_id: 999\n")
    done = run_merlion("doctor", "--config", str(cfg), timeout=60)
    assert done.returncode == 1
    assert done.stdout.splitlines()[0].startswith("FAIL  config") and "mavlink.component_id" in done.stdout
