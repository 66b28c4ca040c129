"""`merlion telemetry` (a real process) against the simulated ArduSub without a position source: it sees depth
from GLOBAL_POSITION_INT at the rate it asked for, and reports LOCAL_POSITION_NED as missing, asked for only a
few times (0, 3 and 9 s after listening 0.2 s) in 10.5 s."""

from __future__ import annotations

import json

import pytest

from tests.conftest import free_udp_port, run_merlion
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import SimVehicle


@pytest.mark.slow
def test_telemetry_command_reports_depth_rates_and_no_position_source(tmp_path):
    port = free_udp_port()
    cfg = tmp_path / "merlion.yaml"
    # the first second of listening, and the 30 s the EKF may take to set its origin, shortened
    cfg.write_text("telemetry:\n  rate_listen_s: 0.2\n  position_wait_s: 2\n")
    dive = compile_profile({"legs": [{"hold": {"s": 1.0}}, {"descend": {"to_m": 20.0, "rate_mps": 0.5}}]})
    with SimVehicle(f"udpin:127.0.0.1:{port}", dive) as sim:
        done = run_merlion("telemetry", "--connect", f"udpout:127.0.0.1:{port}", "--duration", "10.5", "--json",
                           "--config", str(cfg),
                           timeout=60)
        commands = list(sim.commands)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    latest, rates = result["latest"], result["rates"]
    assert latest["depth_source"] == "global_position_int" and latest["depth_m"] > 2.0
    assert latest["position_source"] is False and latest["north_m"] is None
    assert rates["LOCAL_POSITION_NED"]["missing"] and rates["LOCAL_POSITION_NED"]["requests"] == 3
    assert rates["GLOBAL_POSITION_INT"]["observed_hz"] >= 4.0 and not rates["GLOBAL_POSITION_INT"]["missing"]
    assert rates["GLOBAL_POSITION_INT"]["requests"] == 1  # asked once, kept
    assert len([c for c in commands if c[1] == 32.0]) == 3  # the simulator saw the same three requests
    assert "no position source" in done.stderr + done.stdout


def test_telemetry_with_no_autopilot_there_ends_with_one_error_line_and_exit_1():
    endpoint = f"udpin:127.0.0.1:{free_udp_port()}"  # nobody sends here
    done = run_merlion("telemetry", "--connect", endpoint, "--duration", "3", timeout=60)
    assert done.returncode == 1, done.stdout + done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("merlion: error: ")]
    assert errors == [done.stderr.strip().splitlines()[-1]], done.stderr
    assert errors[0].startswith(f"merlion: error: {endpoint}: nothing heard from an autopilot in 3 s")
    assert "Traceback" not in done.stderr
