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


def test_doctor_names_the_cost_of_a_cuda_build_of_torch_on_a_computer_without_gpu() -> None:
    """On a CPU-only companion a CUDA build of torch loads its GPU libraries all the same (~0.28 GB): the doctor
    says so, with the CPU build or the ONNX runtime as the fix; an encoder that needs no torch gets no such line."""
    import torch

    from companion.config import Config
    from companion.live.doctor import OK, WARN, check_cuda

    torch_encoder = Config.model_validate({"encoder": {"name": "imagenet"}})
    no_torch = Config.model_validate({"encoder": {"name": "clip", "runtime": "onnx"}})
    if torch.cuda.is_available():
        assert check_cuda(torch_encoder).status == OK
        return
    check, other = check_cuda(torch_encoder), check_cuda(no_torch)
    assert check.status == other.status == WARN
    assert "CUDA build" not in other.detail
    if torch.version.cuda is None:  # a CPU build already
        assert "CUDA build" not in check.detail
    else:
        assert "is a CUDA build" in check.detail and "MB of memory" in check.detail
        assert "download.pytorch.org/whl/cpu" in check.fix and "encoder.runtime: onnx" in check.fix
