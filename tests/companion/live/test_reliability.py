"""What a dive throws at the companion, with real processes and sockets: it keeps going, or stops with a clear
message, and never loses what it saved."""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import socket
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import StoreConfig
from companion.storage.store import TMP_PREFIX, Store
from tests.companion.live_harness import (
    Companion,
    Listener,
    simulated_vehicle,
    store_summary,
    wait_until,
    write_clip,
    write_config,
)
from tests.conftest import free_udp_port
from vehicle.sim.vehicle import SimVehicle


@pytest.fixture
def vehicle():
    """The live tests' vehicle (conftest.py), with a simulated ArduSub that reboots in 1 s."""
    with simulated_vehicle(reboot_s=1.0) as parts:
        yield parts


def depth_values(listener: Listener) -> list[float]:
    return [m.value for m in listener.of_type("NAMED_VALUE_FLOAT") if m.name == "MRL_DEPTH"]


@pytest.mark.slow
def test_autopilot_silent_then_back_then_rebooted(tmp_path: Path, vehicle) -> None:
    hub, sim, listener = vehicle
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url, "heartbeat_timeout_s": 1.5},
                       store={"dir": str(tmp_path / "store")})
    companion = Companion("--config", str(cfg))
    companion.wait_for("autopilot heartbeat up")
    listener.wait_for(lambda m: m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "MRL_DEPTH"
                      and math.isfinite(m.value), 30, "a depth in the status values")
    mark = companion.mark()
    sim.silence(4.0)
    companion.wait_for("autopilot heartbeat lost", 20, start=mark)
    companion.wait_for("autopilot heartbeat back", 30, start=mark)
    # logged when the loss is declared, then queued for the surface link: the STATUSTEXT comes over the hub later
    wait_until(lambda: any("Autopilot link lost" in t for t in listener.texts()), 10, "the link-lost STATUSTEXT")
    mark = companion.mark()
    seen = len(depth_values(listener))
    sim.reboot()
    # after the reboot (boot time restarts) the companion still tags frames with depth
    wait_until(lambda: any(math.isfinite(v) for v in depth_values(listener)[seen + 4:]), 30,
               "depth after the autopilot rebooted")
    assert companion.alive()
    assert companion.terminate() == 0, companion.output


@pytest.mark.slow
def test_source_lost_then_returning_keeps_the_process_up(tmp_path: Path, vehicle) -> None:
    hub, sim, listener = vehicle
    clip = write_clip(tmp_path / "camera.avi")  # there at start: a file that cannot be read at start is refused
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(tmp_path / "store")},
                       source={"retry_initial_s": 1.0, "retry_max_s": 2.5}, health={"stall_after_s": 1.5})
    companion = Companion("--config", str(cfg), "--source", str(clip), "--loop")
    companion.wait_for("companion running")
    # the source may open after "running" is logged: pulled before its first pass, nothing would be saved to keep
    wait_until(lambda: store_summary(tmp_path / "store").get("summary"), 60, "a summary frame saved before the loss")
    away = clip.rename(tmp_path / "away.avi")  # gone at its next pass, as a camera unplugged mid-dive
    companion.wait_for("retrying in 2.0 s")
    companion.wait_for("retrying in 2.5 s")
    assert "stuck" not in companion.output, "waiting for a camera must not stop the watchdog"
    wait_until(lambda: any("Camera lost" in t for t in listener.texts()), 30, "the camera-lost STATUSTEXT")
    # the surface link keeps serving while the source is gone: status values keep coming
    count = len(listener.of_type("NAMED_VALUE_FLOAT"))
    wait_until(lambda: len(listener.of_type("NAMED_VALUE_FLOAT")) > count + 5, 30, "status while the source is gone")
    away.rename(clip)  # back whole, as a camera plugged in again
    companion.wait_for("back after")
    assert companion.alive()
    assert companion.terminate() == 0, companion.output
    assert check_store_intact(tmp_path / "store")["summary"]  # what was saved is there and whole


def check_store_intact(store: Path) -> dict:
    """Every frame the index names is whole; every visible file parses; indices on disk stay below the next."""
    doc = store_summary(store)
    for index in doc.get("summary", []):
        base = store / "frames" / f"{index:06d}"
        assert cv2.imread(str(base.with_suffix(".jpg"))) is not None, f"frame {index} image is not whole"
        np.load(base.with_suffix(".npy"))
        json.loads(base.with_suffix(".json").read_text())
    for path in (store / "frames").glob("*.json"):
        if not path.name.startswith(TMP_PREFIX):
            json.loads(path.read_text())
    return doc


def test_sigkill_in_the_middle_of_writing_then_restart(tmp_path: Path) -> None:
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", source={"realtime": False, "fps": 25}, sampler={"k": 12},
                       mavlink={"connection": None}, store={"dir": str(store)})
    rng = random.Random(5)
    seen_added: list[int] = []
    changes = store / "changes.jsonl"
    for _ in range(3):
        companion = Companion("--config", str(cfg))
        companion.wait_for("companion running")
        before = len(changes.read_text().splitlines()) if changes.exists() else 0
        wait_until(lambda b=before: changes.exists() and len(changes.read_text().splitlines()) >= b + 3, 60,
                   "writes to the store")
        # kill at a random moment while frames are being written
        with contextlib.suppress(subprocess.TimeoutExpired):
            companion.proc.wait(rng.uniform(0.0, 0.4))
        companion.kill()
        reopened = Store(StoreConfig(dir=str(store)))
        doc = check_store_intact(store)
        assert reopened.summary == [i for i in doc["summary"]]
        assert reopened.next_image_index > max(int(p.name[:6]) for p in (store / "frames").glob("*.json"))
    companion = Companion("--config", str(cfg))
    companion.wait_for("resuming with")
    assert companion.terminate() == 0
    for line in (store / "changes.jsonl").read_text().splitlines():
        with contextlib.suppress(ValueError):
            entry = json.loads(line)
            if entry["kind"] == "added":
                seen_added.append(entry["image_index"])
    assert seen_added == sorted(set(seen_added)), "an image index was reused after a crash"
    check_store_intact(store)


def test_random_and_truncated_mavlink_on_its_socket(tmp_path: Path) -> None:
    port = free_udp_port()
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": f"udpin:127.0.0.1:{port}"},
                       store={"dir": str(tmp_path / "store")})
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    rng = random.Random(7)
    packer = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    good = mav.MAVLink_heartbeat_message(12, 3, 0, 0, 4, 3).pack(packer)
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for _ in range(200):
            junk = bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300)))
            sock.sendto(junk, ("127.0.0.1", port))
            sock.sendto(good[: rng.randint(1, len(good) - 1)], ("127.0.0.1", port))
            sock.sendto(bytes(bad_crc), ("127.0.0.1", port))
    sim = SimVehicle(f"udpout:127.0.0.1:{port}")
    sim.start()
    try:
        companion.wait_for("autopilot heartbeat up", 30)
        assert companion.alive()
    finally:
        sim.stop()
    assert companion.terminate() == 0, companion.output
    final = companion.wait_for("merlion run: seen")
    assert int(final.split("bad MAVLink ")[1].split(",")[0]) > 0


@contextlib.contextmanager
def small_fs(where: Path, options: str):
    where.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


@pytest.mark.parametrize("options, reason", [("size=1m,ro", "read-only file system"), ("size=200k", "disk full")])
def test_read_only_or_full_store_runs_memory_only(tmp_path: Path, options: str, reason: str) -> None:
    with small_fs(tmp_path / "mnt", options) as mnt:
        store = mnt / "store" if "ro" in options else mnt
        cfg = write_config(tmp_path / "c.yaml", source={"realtime": False, "fps": 25,
                                                        "uri": "synthetic://dive?seconds=1&width=480&height=320"},
                           sampler={"k": 12}, mavlink={"connection": None}, store={"dir": str(store)})
        companion = Companion("--config", str(cfg))
        companion.wait_for("keeping the summary in memory only", 90)
        assert companion.alive()
        assert companion.terminate() == 0, companion.output
        final = companion.wait_for("merlion run: seen")
        assert f"memory-only ({reason})" in final
        if "ro" not in options:
            doc = check_store_intact(store)
            resumed = Store(StoreConfig(dir=str(store)))  # the full disk still resumes what it holds
            assert resumed.summary == doc["summary"]
