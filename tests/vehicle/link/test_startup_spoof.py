"""Issue 48 on the real receive path: a keyed companion link (real UDP socket, real MavLink + VehicleTelemetry), the
simulated ArduSub signing with the same key, and an unsigned spoofer claiming to be it (tests/vehicle/spoofer.py:
MAVLink 2 and MAVLink 1 framing, 20/s), started at many moments before and after the companion.

A tagger thread asks ``pose_at(now)`` every 20 ms from the moment the link starts, exactly as the inference loop
tags each frame, and reads the telemetry snapshot the status uses: not one may carry a spoofed depth, position or
attitude, while the real (signed) telemetry does tag frames. The end-to-end version with `merlion run` is in
tests/vehicle/sim/test_spoofer_live.py (slow). With the documented way out (``mavlink.unsigned_autopilot``), the
same spoofer does reach the tags: the check can fail."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import pytest

from companion.config import MavlinkConfig, TelemetryConfig
from tests.conftest import free_udp_port
from tests.vehicle.sim_env import quick_dive
from tests.vehicle.spoofer import Spoofer, is_spoofed
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.link.connection import MavLink
from vehicle.sim.vehicle import SimVehicle

REFUSED_PER_FRAMING = 200
"""Each run goes on until this many spoofed messages per framing were refused (about 2 s of the spoofer)."""


@dataclass
class Tags:
    """What the tagger saw: every pose (as a dict) and every telemetry snapshot."""

    poses: list[dict] = field(default_factory=list)
    snapshots: list[dict] = field(default_factory=list)

    def spoofed(self) -> list[dict]:
        return [p for p in self.poses + self.snapshots if is_spoofed(p)]

    def tagged(self) -> list[dict]:
        return [p for p in self.poses if not p["stale"] and p["depth_m"] is not None]


def _tagger(telemetry: VehicleTelemetry, tags: Tags, stop: threading.Event) -> threading.Thread:
    def run() -> None:
        while not stop.wait(0.02):
            tags.poses.append(telemetry.pose_at(time.time()).to_dict())
            tags.snapshots.append(telemetry.latest.to_dict())
    thread = threading.Thread(target=run, name="tagger", daemon=True)
    thread.start()
    return thread


def _race(tmp_path, *, spoofer_at: float, sim_at: float, framings=(2, 1), unsigned_autopilot: bool = False):
    """One run: the spoofer starts ``spoofer_at`` s after the companion's link (negative: before it, so its datagrams
    are the first to arrive), the signed simulated ArduSub ``sim_at`` s after it. Returns (tags, link, telemetry,
    spoofer, sim) after it ended."""
    key_file = tmp_path / "signing.key"
    key_file.write_text("reef survey 17\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file),
                                                            unsigned_autopilot=unsigned_autopilot))
    telemetry = VehicleTelemetry(link, TelemetryConfig(stale_after_s=1.0), request_rates=False)
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), signing_key_file=str(key_file))
    spoofer = Spoofer(("127.0.0.1", port), framings=framings)
    tags, stop = Tags(), threading.Event()
    events = sorted([(spoofer_at, spoofer.start), (sim_at, sim.start), (0.0, None)], key=lambda e: e[0])
    t0 = time.monotonic() - min(0.0, events[0][0])
    tagger = None
    try:
        for at, start in events:
            time.sleep(max(0.0, t0 + at - time.monotonic()))
            if start is not None:
                start()
                continue
            telemetry.start()  # the companion: its link, telemetry and tagger
            link.start()
            tagger = _tagger(telemetry, tags, stop)
        assert wait_until(lambda: link.autopilot is not None and link.signing.accepted_signed > 0, 10)
        # both on the link for a while: a few hundred spoofed messages refused, and dozens of frames tagged since
        enough = REFUSED_PER_FRAMING * len(framings)
        since = len(tags.poses)
        assert wait_until(lambda: link.signing.spoofed.get((1, 1), 0) >= enough
                          and sum(not p["stale"] for p in tags.poses[since:]) >= 40, 20)
    finally:
        stop.set()
        if tagger is not None:
            tagger.join(2)
        spoofer.stop()
        sim.stop()
        telemetry.stop()
        link.stop()
    return tags, link, telemetry, spoofer, sim


@pytest.mark.parametrize("spoofer_at, sim_at, framings", [
    pytest.param(-1.0, 0.0, (2, 1), id="spoofer-1s-before-the-companion"),
    pytest.param(-1.0, 1.5, (2, 1), id="spoofer-before-and-autopilot-1.5s-late"),
    pytest.param(-1.0, 1.5, (1,), id="mavlink1-only-spoofer-before-and-autopilot-late"),
    pytest.param(0.0, 0.0, (2, 1), id="spoofer-with-the-first-heartbeat"),
    pytest.param(0.2, 0.0, (2, 1), id="spoofer-0.2s-in"),
    pytest.param(0.7, 0.0, (2, 1), id="spoofer-0.7s-in"),
    pytest.param(2.0, 0.0, (2, 1), id="spoofer-2s-in"),
])
def test_no_tag_ever_carries_spoofed_telemetry_whenever_the_spoofer_starts(tmp_path, spoofer_at, sim_at, framings):
    tags, link, telemetry, spoofer, _sim = _race(tmp_path, spoofer_at=spoofer_at, sim_at=sim_at, framings=framings)
    spoofed = tags.spoofed()
    print(f"\nspoofer at {spoofer_at:+.1f} s, autopilot at {sim_at:+.1f} s: {len(tags.poses)} tags, "
          f"{len(tags.tagged())} with depth, {len(spoofed)} spoofed; {spoofer.sent} spoofed packets sent, "
          f"{link.signing.spoofed.get((1, 1), 0)} refused")
    assert spoofed == [], spoofed[:3]
    assert link.signing.spoofed.get((1, 1), 0) > 0  # the spoofer was heard, and refused
    assert len(tags.tagged()) >= 10  # the signed autopilot's telemetry does tag frames
    assert link.autopilot == (1, 1) and link.autopilot_alive
    assert telemetry.boot_clock.reboots == 0  # its "ten minutes up" never moved the autopilot's clock
    assert link.signing.autopilot == "signs with our key"


def test_with_the_way_out_an_early_spoofer_does_reach_the_tags(tmp_path):
    """mavlink.unsigned_autopilot (for an autopilot that cannot sign) gives up the protection until the autopilot's
    first signed message: what the docs say it costs, and proof that the check above can see a spoofed tag."""
    tags, link, _telemetry, _spoofer, _sim = _race(tmp_path, spoofer_at=-1.0, sim_at=1.5, unsigned_autopilot=True)
    assert tags.spoofed(), f"{len(tags.poses)} tags, none spoofed"
    assert link.autopilot == (1, 1)


def test_an_autopilot_that_does_not_sign_is_not_used_and_the_companion_says_so(tmp_path):
    """With a key and an unsigned autopilot (the simulator without one), the companion tags nothing with its
    telemetry, never calls it found, and says why once (log and the STATUSTEXT callback)."""
    key_file = tmp_path / "signing.key"
    key_file.write_text("reef survey 17\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file), heartbeat_timeout_s=1.0))
    telemetry = VehicleTelemetry(link, TelemetryConfig(stale_after_s=1.0), request_rates=False)
    said: list[tuple[str, int]] = []
    link.on_signing_change(lambda text, severity: said.append((text, severity)))
    sim = SimVehicle(f"udpout:127.0.0.1:{port}", quick_dive(), rates={"HEARTBEAT": 5.0})
    telemetry.start()
    link.start()
    sim.start()
    try:
        assert wait_until(lambda: said, 10)
        assert wait_until(lambda: link.signing.spoofed.get((1, 1), 0) > 10, 10)
        assert link.autopilot is None and not link.autopilot_alive
        assert telemetry.latest.depth_m is None and telemetry.pose_at(time.time()).stale
        assert said == [("Autopilot does not sign: telemetry unused", 3)]
    finally:
        sim.stop()
        telemetry.stop()
        link.stop()
