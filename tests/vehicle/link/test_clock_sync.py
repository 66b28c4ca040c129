"""Boot-time mapping: jitter only delays packets, so the estimate is the least delayed one; reboots restart it."""

from __future__ import annotations

import random
import sys
import threading

import pytest

from vehicle.link.clock_sync import BootClock


def test_offset_is_the_smallest_delay_despite_jitter():
    rng = random.Random(3)
    clock = BootClock(window_s=20.0)
    true_offset = 1000.0
    for i in range(200):  # 20 s of 10 Hz messages with 2-40 ms of transport delay
        boot_ms = 5000 + i * 100
        clock.observe(boot_ms, true_offset + boot_ms / 1000 + rng.uniform(0.002, 0.040))
    assert clock.offset == pytest.approx(true_offset, abs=0.003)
    assert clock.to_local(7000) == pytest.approx(true_offset + 7.0, abs=0.003)
    assert clock.reboots == 0


def test_one_very_late_packet_is_not_a_reboot():
    clock = BootClock(reboot_tolerance_s=1.0, jump_samples=3)
    for i in range(10):
        clock.observe(i * 100, 50.0 + i * 0.1)
    assert not clock.observe(1000, 50.0 + 1.0 + 2.5)  # delayed by 2.5 s in a router
    assert clock.offset == pytest.approx(50.0)
    assert clock.reboots == 0


def test_reboot_when_boot_time_goes_back():
    clock = BootClock()
    for i in range(10):
        clock.observe(600_000 + i * 100, 100.0 + i * 0.1)
    assert clock.offset == pytest.approx(100.0 - 600.0)
    assert clock.observe(1500, 103.0)  # the autopilot came back 1.5 s after booting
    assert clock.reboots == 1
    assert clock.offset == pytest.approx(101.5)
    assert clock.to_local(2500) == pytest.approx(104.0)


def test_a_run_of_late_samples_restarts_the_mapping():
    clock = BootClock(reboot_tolerance_s=1.0, jump_samples=3)
    for i in range(10):
        clock.observe(1000 + i * 100, 10.0 + i * 0.1)  # offset 9.0
    # silent for two minutes, rebooted meanwhile, now 100 s into the new boot: boot time looks "ahead"
    results = [clock.observe(100_000 + i * 100, 200.0 + i * 0.1) for i in range(3)]
    assert results == [False, False, False] and clock.resyncs == 1 and clock.reboots == 0
    assert clock.offset == pytest.approx(100.0, abs=0.2)


def test_unsynced_clock_says_so():
    clock = BootClock()
    assert not clock.synced and clock.offset is None and clock.to_local(10) is None


def test_window_follows_drift():
    clock = BootClock(window_s=5.0)
    for i in range(300):  # the autopilot's clock runs 0.2 % slow: offset grows 2 ms per second
        arrival = 10.0 + i * 0.1
        boot_ms = int(i * 100 * 0.998)
        clock.observe(boot_ms, arrival)
    expected = (10.0 + 299 * 0.1) - int(299 * 100 * 0.998) / 1000
    assert clock.offset == pytest.approx(expected, abs=0.015)


def test_offset_read_on_another_thread_never_sees_the_window_half_updated() -> None:
    """observe() empties the window before the new minimum goes in; a frame tagged then got no offset (or an
    IndexError) before the lock."""
    clock = BootClock()
    clock.observe(0, 100.0)
    stop = threading.Event()

    def telemetry_thread() -> None:
        i = 0
        while not stop.is_set():
            i += 1
            clock.observe(i * 10, 100.0 + i * 0.01 - i * 1e-6)  # every sample is the new smallest offset

    previous = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads often, so that a reader lands inside observe()
    writer = threading.Thread(target=telemetry_thread, daemon=True)
    writer.start()
    try:
        misses = sum(clock.offset is None for _ in range(20000))
    finally:
        stop.set()
        writer.join(timeout=5)
        sys.setswitchinterval(previous)
    assert misses == 0
