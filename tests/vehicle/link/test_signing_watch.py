"""Issue 46: the autopilot's signing watched for the whole run, judged by what it does.

The verdict's rules on an injected clock (vehicle/link/autopilot_signing.py), then signing switched on mid-run: a
ground station sends SETUP_SIGNING to the simulated ArduSub on a UDP hub (the vehicle's router) while the
companion's link, telemetry and downlink run beside them. The simulator then signs everything and, like ArduSub on
SERIAL1 and up, drops what is unsigned, or, like its SERIAL0 (``trust_unsigned``), still obeys it. The companion
says each change once: one log line and one STATUSTEXT that reaches the ground station through the router."""

from __future__ import annotations

import hashlib
import logging
from contextlib import contextmanager

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig, TelemetryConfig
from companion.live.udp_hub import UdpHub
from tests.vehicle.sim_env import FAST_LINK, quick_dive
from tests.vehicle.tether import Peer, Repeater, gcs_heartbeat
from tests.waiting import wait_until
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.camera.downlink import Downlink
from vehicle.camera.params import ParamSpec
from vehicle.link import autopilot_signing as sig
from vehicle.link.connection import MavLink
from vehicle.link.signing import now_timestamp
from vehicle.settings import SurfaceConfig
from vehicle.sim.vehicle import SimVehicle

PASSPHRASE = "reef survey 17"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _watch(has_key: bool = False) -> tuple[sig.AutopilotSigning, Clock, list[tuple[str, int]], list[int]]:
    clock, said, probes = Clock(), [], []
    watch = sig.AutopilotSigning(name="t", clock=clock, window_s=1.0, has_key=lambda: has_key, required=lambda: True)
    watch.on_change(lambda text, severity: said.append((text, severity)))

    def probe() -> bool:
        probes.append(1)
        watch.asked()
        return True
    watch._probe = probe
    return watch, clock, said, probes


def _tick(watch: sig.AutopilotSigning, clock: Clock, seconds: float) -> None:
    for _ in range(int(seconds * 10)):
        clock.t += 0.1
        watch.judge(watch._probe)


def test_the_verdict_follows_what_the_autopilot_does_and_each_change_is_said_once():
    watch, clock, said, probes = _watch()
    watch.saw(sig.UNSIGNED)
    _tick(watch, clock, 1.0)
    assert watch.verdict == sig.Verdict(sig.UNSIGNED, True) and said == [] and probes == []  # presumed: no probe
    watch.saw(sig.NEEDS_A_KEY)  # signing switched on: it signs now
    watch.saw(sig.UNSIGNED)  # (a stranger's unsigned claims never outweigh a signature)
    _tick(watch, clock, 0.1)
    assert watch.verdict == sig.Verdict(sig.NEEDS_A_KEY, None) and len(probes) == 1
    for _ in range(30):  # it keeps signing, and our probes go unanswered (SERIAL1)
        watch.saw(sig.NEEDS_A_KEY)
        _tick(watch, clock, 0.1)
    assert watch.verdict == sig.Verdict(sig.NEEDS_A_KEY, False) and watch.verdict.mismatch
    assert len(probes) == sig.PROBES and said == [("Autopilot signs: it ignores us (no key)", 3)]
    watch.answered()  # it answers after all (our request reached it): a change, said once
    _tick(watch, clock, 0.2)
    assert said[1:] == [("Autopilot signs; takes our unsigned requests", 4)] and not watch.verdict.mismatch
    _tick(watch, clock, 2.0)  # silence is no change of signing
    assert watch.signs == sig.NEEDS_A_KEY and len(said) == 2


def test_a_signature_with_our_key_outweighs_unsigned_claims_and_a_bad_first_verdict_is_said():
    watch, clock, said, _probes = _watch(has_key=True)
    watch.saw(sig.UNSIGNED)
    _tick(watch, clock, 0.2)
    assert said == [("Autopilot does not sign: telemetry unused", 3)]  # bad at first sight: said
    watch.saw(sig.SIGNS_WITH_OUR_KEY)
    watch.saw(sig.UNSIGNED)
    _tick(watch, clock, 0.1)
    watch.answered()
    _tick(watch, clock, 0.2)
    assert said[1:] == [("Autopilot signs with our key", 6)] and watch.verdict == sig.Verdict(sig.SIGNS_WITH_OUR_KEY,
                                                                                                True)


class Router:
    """The hub, the simulated ArduSub, the companion's link with telemetry and a downlink, and a ground station."""

    def __init__(self, tmp_path, *, companion_key: bool, serial0: bool) -> None:
        self.hub = UdpHub().start()
        self.sim = SimVehicle(self.hub.url, quick_dive(), rates={"HEARTBEAT": 5.0})
        self.sim.link.signing.trust_unsigned = serial0
        key_file = tmp_path / "signing.key"
        key_file.write_text(PASSPHRASE + "\n")
        self.link = MavLink(self.hub.url, MavlinkConfig(**FAST_LINK,
                                                        signing_key_file=str(key_file) if companion_key else None))
        self.telemetry = VehicleTelemetry(self.link, TelemetryConfig(rate_grace_s=1.0, stale_after_s=1.0))
        self.downlink = Downlink(self.link, SurfaceConfig(budget_bytes_per_s=20000, push=False, status_hz=1),
                                 params=[ParamSpec("MERL_K", 6, 1, 64, integer=True)])
        self.link.on_signing_change(self.downlink.event)
        self.gcs = Peer(self.hub.port, 255, 190)

    def start(self) -> None:
        self.sim.start()
        self.telemetry.start()
        self.link.start()
        self.downlink.start()
        self.gcs.send(gcs_heartbeat())  # the hub learns the ground station

    def switch_signing_on(self) -> None:
        """MAVProxy's `signing setup` mid-dive: SETUP_SIGNING to the autopilot, which has no key yet."""
        self.gcs.send(mav2.MAVLink_setup_signing_message(1, 1, list(KEY), now_timestamp()))

    def texts(self) -> list[str]:
        return [m.text for m in self.gcs.got("STATUSTEXT", (1, 100))]

    def heartbeats(self) -> int:
        return len(self.gcs.got("HEARTBEAT", (1, 100)))

    def stop(self) -> None:
        self.downlink.stop()
        self.telemetry.stop()
        self.link.stop()
        self.sim.stop()
        self.gcs.close()
        self.hub.stop()


@contextmanager
def _router(tmp_path, *, companion_key: bool = False, serial0: bool = False):
    router = Router(tmp_path, companion_key=companion_key, serial0=serial0)
    router.start()
    try:
        yield router
    finally:
        router.stop()


def _said_once(router: Router, text: str, caplog) -> None:
    """``text`` reached the ground station, and after three more companion heartbeats it was still the one such
    STATUSTEXT and the one 'signing changed' log line."""
    assert wait_until(lambda: text in router.texts(), 20), router.texts()
    beats = router.heartbeats()
    assert wait_until(lambda: router.heartbeats() >= beats + 3, 20)
    assert router.texts().count(text) == 1, router.texts()
    changed = [r.getMessage() for r in caplog.records if "signing changed" in r.getMessage()]
    assert len(changed) == 1, changed


@pytest.mark.parametrize("serial0, text, obeys", [
    pytest.param(False, "Autopilot signs: it ignores us (no key)", False, id="serial1-drops-our-requests"),
    pytest.param(True, "Autopilot signs; takes our unsigned requests", True, id="serial0-still-obeys"),
])
def test_signing_switched_on_mid_run_without_a_key_is_judged_by_whether_we_are_obeyed(tmp_path, caplog, serial0,
                                                                                        text, obeys):
    caplog.set_level(logging.INFO, logger="vehicle")
    with _router(tmp_path, serial0=serial0) as router:
        assert wait_until(lambda: router.link.signing.watch.said == sig.Verdict(sig.UNSIGNED, True), 10)
        assert wait_until(lambda: router.telemetry.latest.depth_m is not None, 10)
        router.switch_signing_on()
        assert wait_until(lambda: router.sim.link.signing.enabled, 10)
        _said_once(router, text, caplog)
        assert router.link.signing.watch.verdict == sig.Verdict(sig.NEEDS_A_KEY, obeys)
        assert router.link.signing.mismatch is (not obeys)
        assert router.link.stats()["signing"]["autopilot_changes"][-1] == \
            f"{sig.NEEDS_A_KEY}, {'obeys' if obeys else 'ignores'} us"
        if not obeys:  # what we sent after the switch was dropped by the simulator, silently, as ArduSub does
            assert router.sim.link.signing.rejected.get((1, 100), 0) >= sig.PROBES


def test_signing_switched_on_mid_run_with_our_key_brings_the_autopilots_telemetry_in(tmp_path, caplog):
    """A keyed companion beside an autopilot without a key: its telemetry is not used (said), until the pilot puts
    the same passphrase on it; then it is found, its telemetry tags frames, and the change is said once."""
    caplog.set_level(logging.INFO, logger="vehicle")
    with _router(tmp_path, companion_key=True) as router:
        assert wait_until(lambda: "Autopilot does not sign: telemetry unused" in router.texts(), 10), router.texts()
        assert router.link.autopilot is None and router.telemetry.latest.depth_m is None
        router.switch_signing_on()
        _said_once(router, "Autopilot signs with our key", caplog)
        assert router.link.autopilot == (1, 1) and router.link.autopilot_alive
        assert wait_until(lambda: router.telemetry.latest.depth_m is not None, 10)
        assert router.link.signing.watch.verdict == sig.Verdict(sig.SIGNS_WITH_OUR_KEY, True)


def test_after_a_change_the_verdict_waits_for_fresh_answers_not_old_silence():
    """Requests left unanswered under one signing (SERIAL1, no key) do not decide the next verdict: after the
    autopilot drops its key, it is probed again and its answer decides."""
    watch, clock, said, probes = _watch()
    for _ in range(30):
        watch.saw(sig.NEEDS_A_KEY)
        _tick(watch, clock, 0.1)
    assert watch.verdict == sig.Verdict(sig.NEEDS_A_KEY, False)
    for _ in range(12):  # signing taken off: unsigned from now on, the window forgets the signatures
        watch.saw(sig.UNSIGNED)
        _tick(watch, clock, 0.1)
    assert watch.signs == sig.UNSIGNED and watch.obeys is None and len(probes) == sig.PROBES + 1
    watch.answered()
    _tick(watch, clock, 0.1)
    assert said[-1] == ("Autopilot does not sign", 5) and watch.verdict == sig.Verdict(sig.UNSIGNED, True)
    assert [v.signs for v in watch.changes] == [sig.NEEDS_A_KEY, sig.UNSIGNED]


def test_a_stranger_alternating_forged_signatures_gets_a_few_changes_said_not_a_flapping_verdict(tmp_path, caplog):
    """Issue 46 review: beside the unsigned simulated ArduSub, a stranger sends heartbeats under its ids (1/1) with a
    signature of another key (anyone can: only a signature with OUR key is unforgeable), stops until the verdict is
    back, and again, six times: twelve changes of verdict. A few are said (``CHANGES_SAID``); the rest are counted
    and logged once, and the verdict still follows the evidence."""
    caplog.set_level(logging.INFO, logger="vehicle")
    with _router(tmp_path) as router:
        watch = router.link.signing.watch
        assert wait_until(lambda: watch.said == sig.Verdict(sig.UNSIGNED, True), 10)
        watch.window_s = 0.5  # the stranger's evidence ages out in half a second: a cycle is about a second
        stranger = Peer(router.hub.port, 1, 1, hashlib.sha256(b"another passphrase").digest())
        try:
            for _ in range(6):
                forging = Repeater(stranger, lambda: [mav2.MAVLink_heartbeat_message(
                    mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)], 10)
                assert wait_until(lambda: watch.said == sig.Verdict(sig.NEEDS_A_KEY, True), 20), watch.said
                forging.stop()
                assert wait_until(lambda: watch.said == sig.Verdict(sig.UNSIGNED, True), 20), watch.said
        finally:
            stranger.close()
        assert len(watch.changes) == 13  # the first verdict and twelve changes, all followed
        beats = router.heartbeats()
        assert wait_until(lambda: router.heartbeats() >= beats + 3, 20)  # what was said has reached the station
        said = [t for t in router.texts() if t.startswith("Autopilot")]
        assert len(said) == sig.CHANGES_SAID, said
        assert watch.withheld == 12 - sig.CHANGES_SAID
        assert router.link.stats()["signing"]["autopilot_changes_withheld"] == watch.withheld
        kept = [r.getMessage() for r in caplog.records if "keeps changing" in r.getMessage()]
        changed = [r.getMessage() for r in caplog.records if "signing changed" in r.getMessage()]
        assert len(kept) == 1 and len(changed) == sig.CHANGES_SAID, (kept, changed)
