"""`merlion doctor`'s table is clean: the checks' log lines (the link's open line, the signing ERROR of a key
mismatch) come once each, after the table, not twice inside it (the autopilot and signing checks each open the
link). Against the simulated ArduSub signing with another key than the doctor's."""

from __future__ import annotations

import re
from pathlib import Path

from tests.conftest import free_udp_port, run_merlion
from tests.vehicle.sim_env import quick_dive
from vehicle.sim.vehicle import SimVehicle

CHECK_LINE = re.compile(r"^(ok|warn|FAIL) {2,}\w+ {2,}\S|^ {10,}fix: ")


def test_doctor_logs_each_line_once_and_after_the_table(tmp_path: Path) -> None:
    port = free_udp_port()
    (tmp_path / "sim.key").write_text("reef survey\n")
    (tmp_path / "wrong.key").write_text("not the key\n")
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=str(tmp_path / "sim.key"))
    sim.start()
    try:
        done = run_merlion("doctor", "--wait", "10", "--signing-key", str(tmp_path / "wrong.key"),
                           env={"MERLION__MAVLINK__CONNECTION": f"udpin:127.0.0.1:{port}",
                                "MERLION__STORE__DIR": str(tmp_path / "store")}, timeout=120)
    finally:
        sim.stop()
    assert done.returncode == 1, done.stdout + done.stderr
    table = done.stdout.splitlines()
    assert all(CHECK_LINE.match(line) for line in table[:-1]), table
    assert any(line.startswith("FAIL  signing") and "another key" in line for line in table)
    assert re.fullmatch(r"merlion doctor: \d problem\(s\)", table[-1]), table[-1]  # the verdict ends it
    logged = done.stderr.splitlines()
    opened = [line for line in logged if re.search(rf"MAVLink udpin:127\.0\.0\.1:{port} open$", line)]
    errors = [line for line in logged if " ERROR " in line]
    assert len(opened) == 1, logged
    assert len(errors) == 1 and "signs with another key" in errors[0], logged
