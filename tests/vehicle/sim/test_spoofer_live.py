"""Issue 48 end to end: `merlion run` (a real process) with a signing key beside the simulated ArduSub signing with
the same key, on one UDP hub (the vehicle's router), and issue 48's spoofer (tests/vehicle/spoofer.py: unsigned
HEARTBEAT, GLOBAL_POSITION_INT, SCALED_PRESSURE2, VFR_HUD and ATTITUDE as 1/1, MAVLink 2 and 1, 20/s) started
before the companion, within a second of its first heartbeat, or later. Every sidecar the store writes during the
run is read (frames the summary drops later too): none carries the spoofed depth, position or attitude, and the
frames are tagged with the simulator's depth. The fast version, many start moments on the same receive path, is
tests/vehicle/link/test_startup_spoof.py; docs/security.md gives the figures of 21 runs of this one in a row."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Companion, Listener, wait_until, write_config
from tests.vehicle.sim_env import quick_dive
from tests.vehicle.spoofer import Spoofer, is_spoofed
from vehicle.sim.vehicle import SimVehicle

PASSPHRASE = "reef survey 17"
FRAMES = 8
"""Tagged frames written after the spoofer started before a run ends."""


def _collect(store: Path, seen: dict[str, dict]) -> dict[str, dict]:
    """Every sidecar in the store now, added to ``seen`` (a frame the summary drops later is still judged)."""
    for p in (store / "frames").glob("*.json"):
        if p.name not in seen:
            try:
                seen[p.name] = json.loads(p.read_text())
            except (OSError, ValueError):
                continue  # being written: read on the next pass
    return seen


def _first_camera_heartbeat(m: mav2.MAVLink_message) -> bool:
    return m.get_type() == "HEARTBEAT" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)


@pytest.mark.slow
@pytest.mark.parametrize("spoof_at", ["before", "first-second", "later"])
def test_no_stored_frame_carries_spoofed_telemetry(tmp_path: Path, spoof_at: str) -> None:
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    listener = Listener()
    hub = UdpHub(outputs=[("127.0.0.1", listener.port)]).start()
    sim = SimVehicle(hub.url, quick_dive(), signing_key_file=str(key_file))
    sim.start()
    spoofer = Spoofer((hub.host, hub.port))
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)})
    seen: dict[str, dict] = {}
    companion = None
    try:
        if spoof_at == "before":
            spoofer.start()
        companion = Companion("--config", str(cfg), "--signing-key", str(key_file))
        if spoof_at == "first-second":
            listener.wait_for(_first_camera_heartbeat, 60, "the companion's first heartbeat")
            time.sleep(0.5)  # the moment itself is what is tested: half a second into the companion's life
            spoofer.start()
        companion.wait_for("autopilot heartbeat up")
        if spoof_at == "later":  # once frames are being tagged with the real depth
            wait_until(lambda: any((f.get("pose") or {}).get("depth_m") is not None
                                   for f in _collect(store, seen).values()), 120, "a first tagged frame")
            spoofer.start()
        after = time.time() + 0.5

        def enough() -> bool:
            frames = _collect(store, seen).values()
            return sum(f["capture_time"] > after and (f.get("pose") or {}).get("depth_m") is not None
                       for f in frames) >= FRAMES
        wait_until(enough, 120, f"{FRAMES} tagged frames after the spoofer started")
        companion.wait_for("claiming to be the autopilot 1/1 ignored")
        assert companion.terminate() == 0, companion.output
        _collect(store, seen)
    finally:
        if companion is not None:
            companion.kill()
        spoofer.stop()
        sim.stop()
        hub.stop()
        listener.close()
    poses = [f["pose"] for f in seen.values() if f.get("pose")]
    spoofed = [p for p in poses if is_spoofed(p)]
    tagged = [p for p in poses if p.get("depth_m") is not None]
    print(f"\nspoofer {spoof_at}: {len(seen)} frames stored, {len(tagged)} tagged with depth, {len(spoofed)} spoofed")
    assert spoofed == [], spoofed[:3]
    assert len(tagged) >= FRAMES and max(p["depth_m"] for p in tagged) <= 6.5  # the quick dive's depths only
    assert "autopilot 1/1 found" in companion.output
