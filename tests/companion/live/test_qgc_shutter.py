"""QGroundControl's camera page against the live companion and the simulated ArduSub: shutter, storage, map.

A pymavlink ground station does what QGroundControl's own code does (src/Camera/VehicleCameraControl.cc:
``_initWhenReady``, ``takePhoto``, ``_mavCommandResult``, ``handleCaptureStatus``, ``handleStorageInfo``;
src/Vehicle/Vehicle.cc: ``_handleCameraImageCaptured``): it reads CAMERA_INFORMATION, asks for the storage and
the capture status, presses the shutter (IMAGE_START_CAPTURE, interval 0, count 1), and on ACCEPTED asks for the
capture status every second until it is idle again; it keeps a map marker for every CAMERA_IMAGE_CAPTURED with
``capture_result == 1``, exactly as QGroundControl does (no 0/0 check of its own). The vehicle has no position
source at first (its EKF has no origin); then the ground station sets one (SET_GPS_GLOBAL_ORIGIN), as
QGroundControl and BlueOS do, and the next press lands on the map where the vehicle is.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.companion.export.readers import coco_read, dive_read, fathomnet_read
from tests.companion.live_harness import (
    Companion,
    ftp_get_json,
    ground_ftp,
    simulated_vehicle,
    store_summary,
    wait_until,
    write_config,
)
from tests.conftest import run_merlion
from vehicle.sim.dive_profile import DEFAULT_PROFILE, compile_profile

NAN = float("nan")
ORIGIN = (-33.8568, 151.2153)
BUDGET_MB = 64.0


@pytest.fixture
def no_origin_vehicle():
    """The simulated ArduSub without a position source: its EKF gets an origin only from a ground station."""
    profile = compile_profile({k: v for k, v in DEFAULT_PROFILE.items() if k != "origin"})
    with simulated_vehicle(profile=profile) as parts:
        yield parts


def _command(gcs, listener, cmd: int, *params: float) -> mav.MAVLink_message:
    """COMMAND_LONG to the camera (1/100), sent again until its COMMAND_ACK comes (the first may reach the hub
    before it knows where the companion is); returns the ACK."""
    full = (list(params) + [0.0] * 7)[:7]
    for _ in range(5):
        start = len(listener.messages)
        gcs.mav.command_long_send(1, 100, cmd, 0, *full)
        try:
            return _next(listener, "COMMAND_ACK", start, f"ACK of command {cmd}", 5,
                         lambda m: m.command == cmd)
        except AssertionError:
            continue
    raise AssertionError(f"command {cmd} never acknowledged")


def _next(listener, kind: str, start: int, what: str, timeout: float = 30.0,
          cond=lambda _m: True) -> mav.MAVLink_message:
    """The first ``kind`` from the camera received after message ``start``."""
    return listener.wait_for(lambda m: m.get_type() == kind and m.get_srcComponent() == 100 and cond(m)
                             and m in listener.messages[start:], timeout, what)


def _pace(listener) -> None:
    """QGroundControl's one-second timer between requests, kept by the camera's own 1 Hz heartbeat (a condition,
    not a sleep): a ground station at its pace is never taken for a flood."""
    _next(listener, "HEARTBEAT", len(listener.messages), "the camera's next heartbeat", 10)


def _pilot_frames(store: Path) -> set[int]:
    """Image indices the store keeps as the pilot's (its sidecars say so)."""
    found = set()
    for path in (store / "frames").glob("*.json"):
        try:
            if json.loads(path.read_text()).get("pilot"):
                found.add(int(path.stem))
        except (OSError, ValueError):
            continue  # being written
    return found


def _take_photo(gcs, listener, store: Path) -> mav.MAVLink_message:
    """QGroundControl's ``takePhoto``, then its capture-status polling until idle; the pilot's capture announced
    (told from the sampler's by the store, which marks it: the camera protocol has no field for it)."""
    before = _pilot_frames(store)
    start = len(listener.messages)
    ack = _command(gcs, listener, mav.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1)
    assert ack.result == mav.MAV_RESULT_ACCEPTED  # anything but ACCEPTED/TEMP_REJECTED/FAILED hangs its button
    for _ in range(60):  # every second while not idle, as _captureStatusTimer does
        _pace(listener)
        mark = len(listener.messages)
        _command(gcs, listener, mav.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS, 1)
        status = _next(listener, "CAMERA_CAPTURE_STATUS", mark, "capture status")
        assert math.isfinite(status.available_capacity)
        if status.image_status == 0:
            break
    else:
        raise AssertionError("the shutter stayed 'in progress'")
    (new,) = _pilot_frames(store) - before
    return _next(listener, "CAMERA_IMAGE_CAPTURED", start, "the pilot's capture", cond=lambda m: m.image_index == new)


def _markers(listener) -> list[tuple[float, float]]:
    """QGroundControl's camera trigger points: one per CAMERA_IMAGE_CAPTURED with capture_result 1."""
    return [(m.lat / 1e7, m.lon / 1e7) for m in listener.of_type("CAMERA_IMAGE_CAPTURED") if m.capture_result == 1]


def test_qgc_shutter_storage_and_map_against_the_simulated_ardusub(tmp_path: Path, no_origin_vehicle) -> None:
    hub, sim, listener = no_origin_vehicle
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store),
                       "disk_budget_mb": BUDGET_MB}, sampler={"k": 2},
                       source={"uri": "synthetic://dive?seconds=600&width=160&height=96"})
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    gcs = mavutil.mavlink_connection(f"udpout:{hub.host}:{hub.port}", source_system=255, source_component=190,
                                     dialect="ardupilotmega")
    try:
        gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        # discovery: a shutter is offered (QGroundControl shows its button for this flag)
        mark = len(listener.messages)
        assert _command(gcs, listener, mav.MAV_CMD_REQUEST_MESSAGE, 259).result == mav.MAV_RESULT_ACCEPTED
        info = _next(listener, "CAMERA_INFORMATION", mark, "camera information")
        assert info.flags & mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        # storage, as _requestStorageInfo asks (storage 0 = all, 1 = ask): READY with the store's real room
        mark = len(listener.messages)
        assert _command(gcs, listener, mav.MAV_CMD_REQUEST_STORAGE_INFORMATION, 0, 1).result == \
            mav.MAV_RESULT_ACCEPTED
        storage = _next(listener, "STORAGE_INFORMATION", mark, "storage information")
        assert storage.status == mav.STORAGE_STATUS_READY
        assert storage.total_capacity == pytest.approx(BUDGET_MB)
        assert 0 < storage.available_capacity <= BUDGET_MB and math.isfinite(storage.used_capacity)
        assert storage.available_capacity <= BUDGET_MB - storage.used_capacity + 1e-3  # the budget's rest at most

        # no EKF origin yet: the pilot's capture is kept, announced, and puts no marker on the map
        unplaced = _take_photo(gcs, listener, store)
        assert unplaced.capture_result == 0 and (unplaced.lat, unplaced.lon) == (0, 0)
        first = unplaced.image_index

        # the ground station sets the EKF origin; once the autopilot reports a position, a press lands on the map
        gcs.mav.set_gps_global_origin_send(1, int(ORIGIN[0] * 1e7), int(ORIGIN[1] * 1e7), 0)
        wait_until(lambda: any(m.lat != 0 for m in listener.of_type("GLOBAL_POSITION_INT")), 30,
                   "a global position from the autopilot")
        taken = [first]
        for _ in range(20):  # until the companion's poses have the position too: press again, as a pilot would
            placed = _take_photo(gcs, listener, store)
            taken.append(placed.image_index)
            if placed.capture_result == 1:
                break
        assert placed.capture_result == 1
        assert placed.lat / 1e7 == pytest.approx(ORIGIN[0], abs=0.01) and \
            placed.lon / 1e7 == pytest.approx(ORIGIN[1], abs=0.01)
        second = placed.image_index

        # the storage and the capture status were sent on change too, never with a NaN
        changes = [m for m in listener.of_type("STORAGE_INFORMATION") if m.get_srcComponent() == 100]
        assert len(changes) > 1 and all(math.isfinite(m.available_capacity) for m in changes)

        # pushed and served like every summary frame, marked as the pilot's
        wait_until(lambda: any(m.get_type() == "NAMED_VALUE_INT" and m.name == "MRL_PUSH" and m.value == second
                               for m in listener.messages), 60, "the pilot's frame pushed")
        index = ftp_get_json(ground_ftp(gcs), "/summary/index.json", tmp_path / "index.json")
        served = {f["image_index"]: f for f in index["summary"]}
        assert served[first]["pilot"] and served[second]["pilot"]

        # K = 2 per topic: the sampler trims for room while the pilot's frames are held, and never takes one
        def trimmed_since_first_pilot() -> bool:
            texts = listener.texts()
            since = next(i for i, t in enumerate(texts) if t.startswith(f"Summary +#{first} "))
            return any(t.startswith("Summary -#") for t in texts[since:])

        wait_until(trimmed_since_first_pilot, 120, "the sampler trimming a frame for room")
        held = store_summary(store)
        assert set(taken) <= set(held["summary"])
        assert not any(t.startswith(tuple(f"Summary -#{i} " for i in taken)) for t in listener.texts())
        assert not any(t.startswith("Request flood") for t in listener.texts())  # QGroundControl's pace is fine
        sidecar = json.loads((store / "frames" / f"{second:06d}.json").read_text())
        assert sidecar["pilot"] is True and sidecar["pose"]["lat"] == pytest.approx(ORIGIN[0], abs=0.01)
        assert sidecar["pose"]["water_temp_c"] == 15.0  # the simulated Bar30's SCALED_PRESSURE2.temperature

        # QGroundControl's map: a marker for the placed capture, and none anywhere at 0, 0
        markers = _markers(listener)
        assert markers and all((lat, lon) != (0.0, 0.0) for lat, lon in markers)
        assert companion.terminate() == 0, companion.output
    finally:
        gcs.close()
    _exports_of_the_live_store(store, tmp_path, set(taken))


def _exports_of_the_live_store(store: Path, tmp_path: Path, pilots: set[int]) -> None:
    """The store the live run left, exported and read back by each science tool's own rules."""
    pytest.importorskip("pycocotools")
    pytest.importorskip("fathomnet")
    for fmt in ("coco", "fathomnet", "csv"):
        proc = run_merlion("export", str(store), "--format", fmt, "--out", str(tmp_path / f"live.{fmt}"))
        assert proc.returncode == 0, proc.stderr
    coco = coco_read(tmp_path / "live.coco")  # annToMask on every annotation
    images = {img["frame"]: img for img in coco.loadImgs(coco.getImgIds())}
    assert pilots <= set(images) and all(images[i]["pilot"] for i in pilots)
    assert all(isinstance(img["threshold"], float) and isinstance(img["below_threshold"], bool)
               for img in images.values())
    assert all(img["date_captured"] for img in images.values())
    placed = [img for img in images.values() if "lat" in img]
    assert placed and all((img["lat"], img["lon"]) != (0.0, 0.0) for img in placed)
    records = fathomnet_read(json.loads((tmp_path / "live.fathomnet").read_text()))
    assert all(r.imagingType == "ROV" and r.temperatureCelsius == 15.0 for r in records if r.depthMeters)
    rows = dive_read(tmp_path / "live.csv")  # DIVE's imageMap puts every row on its own frame
    assert {r["attrs"]["frame"] for r in rows if r["attrs"].get("pilot")} == pilots
