"""Who the autopilot is and whether it is alive: settled once, never moved by a stranger, found and lost in order.

Real MAVLink 2 packets (signed with a real key where the test needs it), parsed as the link parses them; the
clock is the test's, so loss is decided without waiting."""

from __future__ import annotations

import hashlib

from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.link.autopilot_watch import AutopilotWatch, is_autopilot_heartbeat

KEY = hashlib.sha256(b"test key").digest()


def _sub_heartbeat() -> mav2.MAVLink_message:
    return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)


def _received(src: tuple[int, int], signed: bool = False) -> mav2.MAVLink_message:
    """A submarine heartbeat from ``src`` as the link's parser hands it over."""
    packer = mav2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    parser = mav2.MAVLink(None)
    parser.signing.secret_key = KEY
    parser.signing.allow_unsigned_callback = lambda _mav, _msg_id: True  # as the link's check, which counts them
    if signed:
        packer.signing.secret_key = KEY
        packer.signing.sign_outgoing = True
        packer.signing.timestamp = 1_000_000
    (msg,) = parser.parse_buffer(_sub_heartbeat().pack(packer))
    assert bool(getattr(msg, "_signed", False)) == signed
    return msg


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _watch(clock: _Clock, adopted: list) -> AutopilotWatch:
    return AutopilotWatch(name="test", clock=clock, timeout_s=3.0, on_adopt=adopted.append)


def test_heartbeat_kinds():
    assert is_autopilot_heartbeat(_sub_heartbeat())
    rover = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GROUND_ROVER, mav2.MAV_AUTOPILOT_PX4, 0, 0, 4, 3)
    assert is_autopilot_heartbeat(rover)
    gcs = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
    camera = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_CAMERA, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
    computer = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_ONBOARD_CONTROLLER, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                              0, 0, 4, 3)
    assert not any(is_autopilot_heartbeat(m) for m in (gcs, camera, computer))


def test_the_first_autopilot_is_kept_and_strangers_and_ground_stations_are_counted_or_ignored():
    clock, adopted = _Clock(), []
    watch = _watch(clock, adopted)
    assert watch.heard(_received((1, 1)))
    assert not watch.heard(_received((42, 1)))
    assert not watch.heard(_received((255, 190)))  # a ground station's system id is never the vehicle's
    assert watch.heard(_received((42, 1), signed=True))
    assert watch.autopilot == (42, 1) and adopted == [(1, 1), (42, 1)]  # an unsigned first one gives way once
    assert not watch.heard(_received((1, 1), signed=True))  # and the signed one is then kept
    assert watch.autopilot == (42, 1) and adopted == [(1, 1), (42, 1)]
    assert watch.foreign_heartbeats == 2 and watch.last_heartbeat.get_srcSystem() == 42


def test_found_and_lost_are_declared_by_the_watching_thread_in_order():
    clock, adopted = _Clock(), []
    watch = _watch(clock, adopted)
    events: list[bool] = []
    watch.on_change(events.append)
    watch.watch(0.0)
    assert events == [] and not watch.alive and not watch.wait_found(0)
    watch.heard(_received((1, 1)))
    assert not watch.alive  # heard, not yet declared: only the watching thread declares
    watch.watch(0.0)
    assert watch.alive and watch.wait_found(0) and events == [True]
    clock.now += 2.9
    watch.watch(0.0)
    assert watch.alive and events == [True]
    clock.now += 0.2
    watch.watch(0.0)
    assert not watch.alive and not watch.wait_found(0) and events == [True, False]
    watch.heard(_received((1, 1)))
    watch.heard(_received((1, 1)))
    watch.watch(0.0)
    watch.watch(0.0)
    assert watch.alive and events == [True, False, True]  # two heartbeats, one "found"
