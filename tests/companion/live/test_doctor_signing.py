"""`merlion doctor`'s signing check against the simulated ArduSub: same key, another key, no key, signing off."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import load_config
from companion.live.doctor import FAIL, OK, WARN, check_signing
from tests.companion.live_harness import write_config
from tests.conftest import free_udp_port, run_merlion
from tests.vehicle.sim_env import quick_dive
from vehicle.sim.vehicle import SimVehicle


def _key(path: Path, passphrase: str) -> str:
    path.write_text(passphrase + "\n")
    return str(path)


@pytest.mark.parametrize("sim_passphrase, status, words", [
    ("reef survey", OK, "answers signed commands"),
    ("another key", FAIL, "signs with another key"),
    (None, WARN, "does not sign"),
])
def test_doctor_tells_whether_the_autopilot_answers_signed_requests(tmp_path: Path, sim_passphrase, status,
                                                                     words) -> None:
    port = free_udp_port()
    ours = _key(tmp_path / "ours.key", "reef survey")
    theirs = _key(tmp_path / "sim.key", sim_passphrase) if sim_passphrase else None
    cfg = load_config(None, overrides={"mavlink": {"connection": f"udpin:127.0.0.1:{port}", "signing_key_file": ours}},
                      environ={})
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0}, signing_key_file=theirs)
    sim.start()
    try:
        check = check_signing(cfg, 5.0)
    finally:
        sim.stop()
    assert check.status == status and words in check.detail, check.line()


def test_doctor_without_a_key_beside_a_signing_autopilot_that_still_obeys_warns_instead_of_failing(tmp_path: Path):
    """Issue 46: ArduSub's SERIAL0 signs but obeys unsigned requests; judged by what it does, that is no failure."""
    port = free_udp_port()
    cfg = load_config(None, overrides={"mavlink": {"connection": f"udpin:127.0.0.1:{port}"}}, environ={})
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=_key(tmp_path / "sim.key", "reef survey"))
    sim.link.signing.trust_unsigned = True
    sim.start()
    try:
        check = check_signing(cfg, 5.0)
    finally:
        sim.stop()
    assert check.status == WARN and "obeys this companion's unsigned requests" in check.detail, check.line()


def test_doctor_says_when_signing_is_off() -> None:
    cfg = load_config(None, environ={})
    check = check_signing(cfg, 1.0)
    assert check.status == WARN and check.detail.startswith("off") and "docs/security.md" in check.fix


def _signing_line(output: str) -> str:
    return next(line for line in output.splitlines() if line.split()[1:2] == ["signing"])


@pytest.mark.slow
def test_merlion_doctor_fails_an_unsigned_or_wrongly_keyed_companion_beside_a_signing_autopilot(tmp_path: Path):
    """Issue 24 item 8: ArduSub with a key drops everything an unsigned companion sends; doctor says so and fails."""
    port = free_udp_port()
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": f"udpin:127.0.0.1:{port}"},
                       store={"dir": str(tmp_path / "store")})
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0},
                     signing_key_file=_key(tmp_path / "sim.key", "reef survey"))
    sim.start()
    try:
        unsigned = run_merlion("doctor", "--config", str(cfg), "--wait", "5")
        wrong = run_merlion("doctor", "--config", str(cfg), "--wait", "5",
                            "--signing-key", _key(tmp_path / "wrong.key", "not the key"))
        right = run_merlion("doctor", "--config", str(cfg), "--wait", "5",
                            "--signing-key", _key(tmp_path / "right.key", "reef survey"))
        missing = run_merlion("doctor", "--config", str(cfg), "--signing-key", str(tmp_path / "nope.key"))
    finally:
        sim.stop()
    line = _signing_line(unsigned.stdout)
    assert line.startswith("FAIL") and "the autopilot signs" in line, unsigned.stdout
    assert "--signing-key" in unsigned.stdout and unsigned.returncode == 1
    line = _signing_line(wrong.stdout)
    assert line.startswith("FAIL") and "another key" in line and wrong.returncode == 1, wrong.stdout
    assert _signing_line(right.stdout).startswith("ok"), right.stdout
    assert missing.returncode == 2 and "nope.key" in missing.stderr and "Traceback" not in missing.stderr
