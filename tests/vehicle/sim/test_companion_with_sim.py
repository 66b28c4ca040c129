"""The live companion (`merlion run`, a real process) beside the simulated ArduSub and a ground station on one
UDP hub, as on a BlueOS vehicle, at the real firmware's stream rates: it never looks like a ground station (no
system id 255, no MANUAL_CONTROL), never triggers a failsafe, and tags frames with depth within 5 cm of the
simulator's true depth at their capture time while the pilot dives the vehicle at 0.5 m/s. The simulated vehicle has no position
source: the companion says so once."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Companion, Listener, wait_until, write_config
from vehicle.sim.dive_profile import compile_profile
from vehicle.sim.vehicle import GCS_SYSID, SimVehicle


class GroundStation:
    """QGroundControl with a joystick, the parts that matter here: a 1 Hz heartbeat as system 255 (it arms the GCS
    failsafe) and MANUAL_CONTROL at 10 Hz with the stick full down (it arms the pilot-input failsafe and dives the
    vehicle at PILOT_SPEED_UP's 1 m/s, PILOT_SPEED_DN being 0)."""

    def __init__(self, hub: UdpHub) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.mav = mav2.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=190)
        self.hub = (hub.host, hub.port)
        self.piloting_since = time.time()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        tick = 0
        while not self._stop.is_set():
            if tick % 10 == 0:
                hb = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
                self.sock.sendto(hb.pack(self.mav), self.hub)
            stick = mav2.MAVLink_manual_control_message(1, 0, 0, 0, 0, 0)  # z 0: full down
            self.sock.sendto(stick.pack(self.mav), self.hub)
            tick += 1
            self._stop.wait(0.1)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=3)
        self.sock.close()


def _tagged_frames(store: Path) -> list[dict]:
    frames = []
    for p in (store / "frames").glob("*.json"):
        try:
            frames.append(json.loads(p.read_text()))
        except (OSError, ValueError):
            continue  # being written
    return [f for f in frames if f.get("pose") and f["pose"].get("depth_m") is not None]


@pytest.mark.slow
def test_live_companion_never_looks_like_a_gcs_and_tags_depth_within_5_cm(tmp_path: Path) -> None:
    listener = Listener()
    hub = UdpHub(outputs=[("127.0.0.1", listener.port)]).start()
    dive = compile_profile({"legs": [{"hold": {"s": 600.0, "mode": "ALT_HOLD"}}]})  # the pilot flies it
    sim = SimVehicle(hub.url, dive, clock=time.time)  # wall clock: the frames' capture times index its truth
    sim.start()
    gcs = GroundStation(hub)
    store = tmp_path / "store"
    # the companion asks for what the firmware sends anyway: GLOBAL_POSITION_INT 3.2 Hz, SCALED_PRESSURE2 1 Hz
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       telemetry={"position_hz": 3.2, "pressure_hz": 1.0, "position_wait_s": 5.0})
    companion = Companion("--config", str(cfg))
    try:
        companion.wait_for("autopilot heartbeat up")
        up = time.time()
        wait_until(lambda: (GCS_SYSID, 190, mav2.MAV_TYPE_GCS) in sim.heartbeat_senders, 10, "the GCS heartbeat")
        # the pilot may start before the companion is up (it starts faster now): GLOBAL_POSITION_INT is asked for
        # when the autopilot is found, and until it flows the firmware's default SCALED_PRESSURE2 rightly stands in
        descending = max(gcs.piloting_since + 1.0, up + 1.5)
        wait_until(lambda: sum(f["capture_time"] > descending for f in _tagged_frames(store)) >= 5, 90,
                   "five frames tagged during the descent")
        # the simulated vehicle has no position source: said once, in the log and as one STATUSTEXT (~9 s in)
        listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and m.text.startswith("No position source"), 30,
                          "the no-position-source STATUSTEXT")
        companion.wait_for("no position source")
        assert companion.terminate() == 0, companion.output
        assert sum(t.startswith("No position source") for t in listener.texts()) == 1
        frames = [f for f in _tagged_frames(store) if f["capture_time"] > descending]
        assert sim.state().vd == 1.0 and sim.state().depth > 2.0 and sim.state().armed
        errors = [abs(f["pose"]["depth_m"] - sim.state_at(f["capture_time"] - sim._start).depth) for f in frames]
        assert max(errors) <= 0.05, sorted(errors)
        assert {f["pose"]["depth_source"] for f in frames} == {"global_position_int"}
    finally:
        companion.kill()
        gcs.stop()
        sim.stop()
        hub.stop()
        listener.close()
    ours = {s for s in sim.heartbeat_senders if s[2] != mav2.MAV_TYPE_GCS}
    assert ours and all(system == sim.link.system_id for system, _c, _t in ours), sim.heartbeat_senders
    assert {s[:2] for s in sim.heartbeat_senders if s[0] == GCS_SYSID} == {(GCS_SYSID, 190)}
    assert sim.manual_control_senders == {(GCS_SYSID, 190)}  # the pilot's, and nobody else's
    assert sim.failsafes == [] and not [t for _s, t in sim.statustexts if "failsafe" in t.lower()]
    camera = [m for m in listener.of_type("HEARTBEAT") if m.type == mav2.MAV_TYPE_CAMERA]
    assert camera and {(m.get_srcSystem(), m.get_srcComponent()) for m in camera} == {(1, 100)}
