"""The depth track's times (issue 25): the surface places each MRL_DEPTH value at the companion's time of measuring
it, not at its arrival, so during a descent the summary dots (capture time, depth at capture) sit on the track."""

from __future__ import annotations

import numpy as np

from companion.topside.boot_clock import BootClock
from vehicle.camera.status import NAME_DEPTH, StatusReporter

DESCENT_M_PER_S = 0.5
BOOT_AT = 1.7e9  # the surface's clock when the companion booted


def depth_at(t: float) -> float:
    return 2.0 + DESCENT_M_PER_S * t


def test_a_descent_track_is_placed_at_measuring_time_not_arrival():
    rng = np.random.default_rng(25)
    clock = {"ms": 0}
    reporter = StatusReporter(lambda: clock["ms"])
    boot = BootClock()
    old_error, new_error = [], []
    for tick in range(60):  # the companion measures depth once a second ...
        measured_s = tick + 0.3
        clock["ms"] = int(measured_s * 1000)
        reporter.update(depth_m=depth_at(measured_s))
        clock["ms"] += int(rng.uniform(0, 1000))  # ... the status tick sends it up to a second later ...
        messages = reporter.messages()
        (depth_msg,) = [m for m in messages if m.name.rstrip("\0") == NAME_DEPTH]
        assert depth_msg.time_boot_ms == int(measured_s * 1000)  # stamped when measured, not when sent
        arrival = BOOT_AT + clock["ms"] / 1000 + rng.uniform(0.05, 1.5)  # ... behind thumbnails in the budget
        for other in messages:  # the tool feeds the clock every value of the set, as they arrive
            if other is not depth_msg:
                boot.local(other.time_boot_ms, arrival)
        placed = boot.local(depth_msg.time_boot_ms, arrival)
        # the track's depth at the time a capture at ``placed`` would show: how far off the dot would sit
        new_error.append(abs(depth_at(placed - BOOT_AT) - depth_msg.value))
        old_error.append(abs(depth_at(arrival - BOOT_AT) - depth_msg.value))
    assert max(old_error[10:]) > 0.5  # arrival time: the dots sat up to ~2 s (1 m) off the track
    assert max(new_error[10:]) <= 0.05  # measuring time: within the SITL target of 0.05 m


def test_a_restarted_companion_starts_the_estimate_afresh():
    boot = BootClock()
    assert boot.local(100_000, BOOT_AT + 100.2) == BOOT_AT + 100.2
    assert abs(boot.local(101_000, BOOT_AT + 101.1) - (BOOT_AT + 101.1)) < 1e-6  # a faster message: new offset
    assert abs(boot.local(102_000, BOOT_AT + 103.0) - (BOOT_AT + 102.1)) < 1e-6  # a slow one keeps the best
    restarted = boot.local(2_000, BOOT_AT + 300.0)  # boot time went back: a new boot, a new offset
    assert restarted == BOOT_AT + 300.0


def _window_minimum(events: list[tuple[int, float]], window_s: float = 120.0) -> list[float]:
    """What BootClock must answer: each boot time plus the least offset of the messages of the last window."""
    out, kept = [], []
    for ms, arrival in events:
        kept = [(a, o) for a, o in kept if a >= arrival - window_s] + [(arrival, arrival - ms / 1000.0)]
        out.append(ms / 1000.0 + min(o for _, o in kept))
    return out


def test_the_window_minimum_is_kept_without_scanning_every_message():
    rng = np.random.default_rng(7)
    events, ms, arrival = [], 0, BOOT_AT
    for _ in range(3000):  # 25 minutes of values, each delayed 0-2 s on the way
        ms += int(rng.integers(100, 1000))
        arrival = max(arrival, BOOT_AT + ms / 1000.0 + float(rng.uniform(0.0, 2.0)))
        events.append((ms, arrival))
    boot = BootClock()
    assert [boot.local(ms, a) for ms, a in events] == _window_minimum(events)


def test_a_flood_of_values_keeps_a_bounded_number_of_offsets():
    """Offsets that rise with every message (each delayed a little more) are all candidates for the minimum once
    the older ones age out: at most MAX_KEPT are kept, however fast they come."""
    from companion.topside.boot_clock import MAX_KEPT

    boot = BootClock()
    for i in range(50_000):
        boot.local(i, BOOT_AT + i / 1000.0 + i * 1e-6)  # within one window: 50 s
    assert len(boot._offsets) == MAX_KEPT
