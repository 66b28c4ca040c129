"""The link's two races of docs/code-review.md, on real loopback sockets with real MAVLink messages.

The heartbeat race is run 30 times with a short thread switch interval (threads interleave between almost any two
bytecodes); the rate keeper's is forced once by a clock that stalls the rates thread at the racy line (as a
preemption would). Each fails if any run goes wrong; with one owner thread per state, none can.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from tests.conftest import free_udp_port
from vehicle.link.connection import MavLink
from vehicle.link.message_rates import RateKeeper

TIMEOUT_S = 2.0
ROUNDS = 30


@pytest.fixture
def fine_switching():
    """Threads switch every 10 us instead of 5 ms: a window of a few bytecodes is hit often."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    yield
    sys.setswitchinterval(before)


class _Autopilot:
    """A raw UDP socket that sends packed ArduSub messages (system 1, component 1) to the link's port."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.addr = ("127.0.0.1", port)
        self.mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)

    def heartbeat(self) -> None:
        msg = mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)
        self.sock.sendto(msg.pack(self.mav), self.addr)

    def close(self) -> None:
        self.sock.close()



class _JumpingClock:
    """Monotonic time that the test moves past the heartbeat timeout: the timer thread's next look at the clock
    jumps it and, at that very moment, the autopilot's next heartbeat is sent, so it is heard while the loss is
    being declared."""

    def __init__(self) -> None:
        self.offset = 0.0
        self.armed: Callable[[], None] | None = None
        self.jumped = threading.Event()

    def __call__(self) -> float:
        action = self.armed
        if action is not None and threading.current_thread().name.endswith("-mavlink-hb"):
            self.armed = None
            self.offset += TIMEOUT_S + 1.0
            action()
            self.jumped.set()
        return time.monotonic() + self.offset


def test_a_heartbeat_heard_while_the_loss_is_declared_is_never_left_reported_lost(fine_switching) -> None:
    port = free_udp_port()
    clock = _JumpingClock()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(heartbeat_timeout_s=TIMEOUT_S), clock=clock,
                   heartbeat=False)
    # the jump is meant for the autopilot watch's look at the clock; the signing watch and the refusal log read the
    # same clock on the same thread, and a jump taken there let the heartbeat land before the loss (29 of 30)
    link.signing.watch.clock = time.monotonic
    link.signing.refusal_log.clock = time.monotonic
    events: list[bool] = []
    changed = threading.Condition()

    def say_it(alive: bool) -> None:  # as the companion's AutopilotNotice does: a STATUSTEXT through the link
        link.send(mav2.MAVLink_statustext_message(6, b"autopilot up" if alive else b"autopilot lost"))

    def record(alive: bool) -> None:
        with changed:
            events.append(alive)
            changed.notify_all()

    link.on_autopilot(say_it)
    link.on_autopilot(record)
    autopilot = _Autopilot(port)
    link.start()
    bad: list[str] = []
    try:
        assert link.wait_open(5)
        autopilot.heartbeat()
        with changed:
            assert changed.wait_for(lambda: events == [True], 5)
        for round_ in range(ROUNDS):
            heard = link.rx_messages
            clock.jumped.clear()
            clock.armed = autopilot.heartbeat
            assert clock.jumped.wait(5)
            with changed:  # the heartbeat was heard: what the link says must end "alive", everywhere
                settled = changed.wait_for(
                    lambda heard=heard: link.rx_messages > heard and events[-1] and link.autopilot_alive, 1.5)
            if not settled:
                bad.append(f"round {round_}: autopilot_alive={link.autopilot_alive}, last callback {events[-1]}")
                autopilot.heartbeat()  # put it right for the next round
                with changed:
                    changed.wait_for(lambda: events[-1] and link.autopilot_alive, 2.0)
    finally:
        link.stop()
        autopilot.close()
    assert not bad, f"{len(bad)} of {ROUNDS} rounds left the autopilot reported lost: {bad[:3]}"
    assert all(a != b for a, b in zip(events, events[1:], strict=False)), f"found/lost out of order: {events}"
    assert events[-1] is True and events.count(False) >= ROUNDS  # every jump was a real loss, each one recovered


class _StalledRatesClock:
    """The rates thread's clock, which stalls once, right after the thread's first request went out (where it notes
    when it asked), until the test says go: the thread is preempted there while the autopilot is lost and found."""

    def __init__(self, keeper_requests: Callable[[], int]) -> None:
        self.requests = keeper_requests
        self.stalled = threading.Event()
        self.go = threading.Event()

    def __call__(self) -> float:
        if (threading.current_thread().name == "mavlink-rates" and self.requests() >= 1
                and not self.stalled.is_set()):
            self.stalled.set()
            self.go.wait(10)
        return time.monotonic()


def test_the_autopilot_found_again_during_a_request_gets_every_rate_asked_again() -> None:
    port = free_udp_port()
    # 2 s without a heartbeat is a loss: a loaded machine's stall of a 10 Hz beat must not fake one
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(heartbeat_timeout_s=2.0), heartbeat=False)
    autopilot = _Autopilot(port)
    beating = threading.Event()
    beating.set()
    running = threading.Event()
    running.set()

    def beat() -> None:  # the autopilot's heartbeat at 10 Hz, while ``beating``
        while running.is_set():
            if beating.is_set():
                autopilot.heartbeat()
            time.sleep(0.1)

    keeper: RateKeeper | None = None
    clock = _StalledRatesClock(lambda: keeper.requests["ATTITUDE"] if keeper else 0)
    keeper = RateKeeper(link, {"ATTITUDE": 10.0}, ack_timeout_s=0.05, retries=0, grace_s=30.0, clock=clock)
    beats = threading.Thread(target=beat)
    link.start()
    beats.start()
    try:
        assert link.wait_autopilot(5)
        keeper.start()
        events: list[bool] = []
        link.on_autopilot(events.append)  # after the keeper's: it has run when this one sees a change
        assert clock.stalled.wait(5), "the keeper never asked for ATTITUDE"
        beating.clear()  # lost ...
        deadline = time.monotonic() + 5
        while events != [False] and time.monotonic() < deadline:
            time.sleep(0.02)
        beating.set()  # ... and found again while the keeper is still inside its first request
        while events != [False, True] and time.monotonic() < deadline:
            time.sleep(0.02)
        assert events == [False, True]
        clock.go.set()
        deadline = time.monotonic() + 5
        while keeper.requests["ATTITUDE"] < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert keeper.requests["ATTITUDE"] == 2, "the keeper did not ask again after the autopilot came back"
        assert keeper._thread is not None and keeper._thread.is_alive()
    finally:
        running.clear()
        clock.go.set()
        beats.join(5)
        keeper.stop()
        link.stop()
        autopilot.close()
