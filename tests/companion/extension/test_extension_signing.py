"""`merlion extension` with a signing companion (``mavlink.signing_key_file`` in its configuration): the extension's
own MAVLink ends use the key too. Its page shows only what the signed companion sends (an unsigned attacker on the
vehicle's router, claiming the companion's ids, changes nothing), and its mark and topic actions still work: the
surface tool and the topic switch sign what they send, which a signing companion requires of FTP writes."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.extension.metadata import TITLE
from tests.companion.live_harness import simulated_vehicle, wait_until, write_config
from tests.companion.surface_peer import summary_frame
from tests.conftest import REPO, stop_process
from vehicle.camera.captures import captured_message

from .test_extension import request

ORIGIN = {"Origin": "http://blueos.local"}
"""A page the vehicle serves (BlueOS's own name)."""


@pytest.fixture(scope="module")
def signed(tmp_path_factory):
    root = tmp_path_factory.mktemp("signed")
    key = root / "signing.key"
    key.write_text("tether passphrase\n")
    cfg = write_config(root / "merlion.yaml", sampler={"k": 4}, queries={"tau_ss": 0.3},
                       surface={"budget_bytes_per_s": 40000, "status_hz": 2, "ftp_writable": True},
                       mavlink={"signing_key_file": str(key)})
    with simulated_vehicle() as (router, _sim, _listener), open(root / "extension.log", "wb") as ext_log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion", "extension", "--data", str(root / "data"), "--port", "0",
             "--host", "127.0.0.1", "--router", f"127.0.0.1:{router.port}", "--config", str(cfg),
             "--source", "synthetic://dive?seconds=600&width=320&height=192"],
            cwd=REPO, stdout=subprocess.PIPE, stderr=ext_log, text=True)
        try:
            line = proc.stdout.readline()
            match = re.search(r"page at http://127\.0\.0\.1:(\d+)/", line)
            assert match, f"no page line: {line!r} (exit {proc.poll()})"
            yield f"http://127.0.0.1:{match.group(1)}", router.port, root
        finally:
            stop_process(proc, 60)


def _state(base: str) -> dict:
    return json.loads(request(f"{base}/api/state")[2])


def _post(base: str, action: str, body: dict) -> tuple[int, dict]:
    status, _, answer = request(f"{base}/api/{action}", "POST", headers=ORIGIN, body=json.dumps(body).encode())
    return status, json.loads(answer)


def test_signed_ends_show_only_the_signed_companion_and_their_actions_work(signed):
    base, router_port, root = signed
    assert json.loads(request(f"{base}/register_service")[2])["name"] == TITLE
    wait_until(lambda: len(_state(base)["summary"]) >= 2, 180, "two summary frames from the signed companion")
    state = _state(base)
    assert state["companion"]["id"] is not None
    system, component = state["companion"]["id"]

    # an unsigned attacker on the vehicle's router, as the companion itself: a capture at 123 m, a critical text
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender = mav.MAVLink(None, srcSystem=system, srcComponent=component)
    spoofs = [mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, b"MERLION: fake critical"),
              captured_message(summary_frame(4242, depth=123.0), 1000, dive=state["dive"])]
    for msg in spoofs:
        attacker.sendto(msg.pack(sender), ("127.0.0.1", router_port))
    attacker.close()
    sent = len(spoofs)
    # counted under the ids they claimed (the simulated autopilot's unsigned telemetry is counted apart, as 1/1)
    wait_until(lambda: _state(base)["link"]["unsigned_sources"].get(f"{system}/{component}", 0) >= sent, 30,
               "the unsigned messages counted")
    state = _state(base)
    assert not any("fake critical" in line["text"] for line in state["companion"]["statustext"])
    assert 4242 not in [f["image_index"] for f in state["summary"]]
    assert all(f["depth_m"] is None or f["depth_m"] < 100 for f in state["summary"])

    # the actions sign: the companion takes the marks and the topic (it refuses unsigned FTP writes)
    status, answer = _post(base, "mark-newest", {"kind": "like"})
    assert status == 200 and answer["marks"]["like"], answer
    status, answer = _post(base, "topic", {"topic": "main"})
    assert status == 200 and answer["topic"] == "main", answer
    log = (root / "data" / "companion.log").read_text(errors="replace")
    assert "marks set: like" in log and "file protected" not in log
