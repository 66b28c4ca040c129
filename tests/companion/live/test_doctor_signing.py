"""`merlion doctor`'s signing check against the simulated ArduSub: same key, another key, no key, signing off."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import load_config
from companion.live.doctor import FAIL, OK, WARN, check_signing
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import quick_dive
from vehicle.sim.vehicle import SimVehicle


def _key(path: Path, passphrase: str) -> str:
    path.write_text(passphrase + "\n")
    return str(path)


@pytest.mark.parametrize("sim_passphrase, status, words", [
    ("reef survey", OK, "answers signed commands"),
    ("another key", FAIL, "ignores our signed commands"),
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


def test_doctor_says_when_signing_is_off() -> None:
    cfg = load_config(None, environ={})
    check = check_signing(cfg, 1.0)
    assert check.status == WARN and check.detail.startswith("off") and "docs/security.md" in check.fix
