"""The camera component as a ground station sees it: discovery, captures, re-requests, NaN parameters, ACKs."""

from __future__ import annotations

import json
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import SurfaceConfig
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import added, companion_link, ground_station, removed, summary_frame, wait_for
from vehicle.autopilot.pose import Pose
from vehicle.camera.captures import CaptureLog, captured_message, quaternion
from vehicle.camera.component import CameraComponent
from vehicle.camera.downlink import Downlink
from vehicle.camera.storage import MIB, StorageSpace
from vehicle.link.budget import Priority

NAN = float("nan")


def _cmd(command, p1=NAN, p2=NAN, *, target=(1, 100)):
    msg = mav.MAVLink_command_long_message(target[0], target[1], command, 0, p1, p2, NAN, NAN, NAN, NAN, NAN)
    msg._header = mav.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)
    return msg


@pytest.fixture
def camera():
    log = CaptureLog(initial_count=40)
    return CameraComponent(log, system_id=lambda: 1, component_id=100), log


def test_every_command_for_us_is_acknowledged(camera):
    cam, _ = camera
    info = cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 259))
    assert [m.get_type() for m in info] == ["COMMAND_ACK", "CAMERA_INFORMATION"]
    assert (info[0].result, info[0].target_system, info[0].target_component) == (mav.MAV_RESULT_ACCEPTED, 255, 190)
    assert bytes(info[1].vendor_name).rstrip(b"\0") == b"MERLION"
    assert info[1].cam_definition_uri in ("", b"")
    # no shutter wired (no companion behind the link): no shutter offered, and a press is UNSUPPORTED
    assert not info[1].flags & mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
    for unsupported in (_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 260), _cmd(mav.MAV_CMD_REQUEST_MESSAGE, 270),
                        _cmd(mav.MAV_CMD_IMAGE_START_CAPTURE)):
        (ack,) = cam.handle(unsupported)
        assert ack.result == mav.MAV_RESULT_UNSUPPORTED
    (ack,) = cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, NAN))  # which message? unset: denied, never int(NaN)
    assert ack.result == mav.MAV_RESULT_DENIED
    assert cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 259, target=(1, 1))) == []  # the autopilot's
    assert cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 259, target=(2, 100))) == []  # another vehicle's
    assert cam.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=(1, 0))) == []  # broadcast, not ours
    assert len(cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 259, target=(1, 0)))) == 2  # broadcast discovery
    as_int = mav.MAVLink_command_int_message(1, 100, 0, mav.MAV_CMD_REQUEST_MESSAGE, 0, 0, 262, NAN, NAN, NAN,
                                             0, 0, NAN)
    as_int._header = mav.MAVLink_header(as_int.id, srcSystem=255, srcComponent=190)
    assert [m.get_type() for m in cam.handle(as_int)] == ["COMMAND_ACK", "CAMERA_CAPTURE_STATUS"]


def test_storage_reports_the_stores_room_and_never_nan(camera):
    cam, _ = camera
    for request in (_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 261), _cmd(mav.MAV_CMD_REQUEST_STORAGE_INFORMATION, 0, 1)):
        ack, info = cam.handle(request)
        assert ack.result == mav.MAV_RESULT_ACCEPTED
        assert info.status == mav.STORAGE_STATUS_NOT_SUPPORTED  # no store behind this link
        assert (info.total_capacity, info.available_capacity) == (0.0, 0.0)
    cam.storage = lambda: StorageSpace(total=2048 * MIB, used=300 * MIB, available=1748 * MIB)
    for request in (_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 261), _cmd(mav.MAV_CMD_REQUEST_STORAGE_INFORMATION, 1, 1),
                    _cmd(mav.MAV_CMD_REQUEST_MESSAGE, 261, target=(1, 0))):
        ack, info = cam.handle(request)
        assert (info.status, info.storage_id, info.storage_count) == (mav.STORAGE_STATUS_READY, 1, 1)
        assert (info.total_capacity, info.used_capacity, info.available_capacity) == (2048.0, 300.0, 1748.0)
    (other,) = cam.handle(_cmd(mav.MAV_CMD_REQUEST_STORAGE_INFORMATION, 2, 1))  # a second storage: there is none
    assert other.result == mav.MAV_RESULT_DENIED
    status = cam.handle(_cmd(mav.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS, 1))[1]
    assert status.available_capacity == 1748.0 and math.isfinite(status.available_capacity)
    assert status.image_status == 0


def test_the_shutter_answers_at_once_and_is_busy_until_the_capture_is_done(camera):
    cam, _ = camera
    finish: list = []
    frames = iter([None, "frame"])  # the first press finds no camera frame yet

    def take(done):
        if next(frames) is None:
            return False
        finish.append(done)
        return True

    cam.shutter.wire(take)
    assert cam.information().flags & mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE  # now QGroundControl shows a shutter
    press = mav.MAVLink_command_long_message(1, 100, mav.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 1, NAN, NAN, NAN, NAN)
    press._header = mav.MAVLink_header(press.id, srcSystem=255, srcComponent=190)
    (ack,) = cam.handle(press)
    assert ack.result == mav.MAV_RESULT_TEMPORARILY_REJECTED  # QGroundControl retries, then resets its button
    assert cam.capture_status().image_status == 0
    (ack,) = cam.handle(press)
    assert ack.result == mav.MAV_RESULT_ACCEPTED and len(finish) == 1
    assert cam.capture_status().image_status == 1  # in progress: QGroundControl asks again a second later
    (again,) = cam.handle(press)  # a press while one is kept (a flood: QGroundControl waits): one at a time
    assert again.result == mav.MAV_RESULT_TEMPORARILY_REJECTED and len(finish) == 1
    finish[0](True)
    assert cam.capture_status().image_status == 0  # idle: its shutter button is ready again
    series = mav.MAVLink_command_long_message(1, 100, mav.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 2, 0, NAN, NAN, NAN,
                                              NAN)
    series._header = press._header
    ack, status = cam.handle(series)  # time-lapse forever: the summary is the series
    assert ack.result == mav.MAV_RESULT_DENIED and len(finish) == 1
    # QGroundControl leaves its button "in progress" on DENIED; the capture status that follows sets it idle
    assert status.get_type() == "CAMERA_CAPTURE_STATUS" and status.image_status == 0
    (ack,) = cam.handle(_cmd(mav.MAV_CMD_IMAGE_STOP_CAPTURE, 0))
    assert ack.result == mav.MAV_RESULT_ACCEPTED


def test_captures_are_answerable_by_index(camera):
    cam, log = camera
    for i in (41, 42):
        log.record(summary_frame(i))
    status = cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 262))[1]
    assert status.image_count == 42
    by_512 = cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 263, 41))[1]
    by_2002 = cam.handle(_cmd(mav.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE, 41))[1]
    assert by_512.image_index == by_2002.image_index == 41
    latest = cam.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 263, NAN))[1]
    assert latest.image_index == 42
    (missing,) = cam.handle(_cmd(mav.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE, 7))
    assert missing.result == mav.MAV_RESULT_FAILED
    (bad,) = cam.handle(_cmd(mav.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE, NAN))
    assert bad.result == mav.MAV_RESULT_DENIED


def test_old_captures_come_from_the_loader():
    log = CaptureLog(loader=lambda i: summary_frame(i) if i == 3 else None)
    assert log.get(3).image_index == 3 and log.get(4) is None


def test_capture_tags():
    frame = summary_frame(9, depth=12.5, lat=1.2834)
    msg = captured_message(frame, 1234)
    assert (msg.relative_alt, msg.lat, msg.lon, msg.image_index, msg.capture_result) == (-12500, 12834000, 1038000000, 9, 1)
    assert msg.time_utc == 1_700_000_009 * 1_000_000
    assert msg.file_url in ("mftp://summary/9.jpg", b"mftp://summary/9.jpg")
    assert msg.q == pytest.approx([0.8253, 0.0, 0.0, 0.5646])
    stale = Pose(time=0.0, age_s=9.0, stale=True, depth_m=3.0)
    assert math.isnan(quaternion(stale)[0])
    euler = Pose(time=0.0, age_s=0.0, stale=False, roll=0.0, pitch=0.0, yaw=math.pi / 2)
    assert quaternion(euler) == pytest.approx((math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)))


def test_ground_station_discovers_the_camera_and_sees_captures_over_udp():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, push=False), image_count=5)
    surface.start()
    gcs = ground_station(port)
    try:
        hb = wait_for(gcs, "HEARTBEAT", cond=lambda m: m.get_srcComponent() == 100)
        assert hb.type == mav.MAV_TYPE_CAMERA
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0, 259, NAN, NAN, NAN, NAN, NAN, NAN)
        ack = wait_for(gcs, "COMMAND_ACK", cond=lambda m: m.command == mav.MAV_CMD_REQUEST_MESSAGE)
        assert ack.result == mav.MAV_RESULT_ACCEPTED
        info = wait_for(gcs, "CAMERA_INFORMATION")
        assert info.get_srcSystem() == 1 and info.get_srcComponent() == 100
        surface.publish(added(6, [6]))
        assert surface.camera.information().resolution_h == 480  # learnt from the frames
        cap = wait_for(gcs, "CAMERA_IMAGE_CAPTURED")
        assert (cap.image_index, cap.relative_alt, cap.file_url) == (6, -12500, "mftp://summary/6.jpg")
        text = wait_for(gcs, "STATUSTEXT", cond=lambda m: "#6" in m.text)
        assert text.severity == mav.MAV_SEVERITY_INFO and len(text.text) <= 50
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0, 262, NAN, NAN, NAN, NAN, NAN, NAN)
        assert wait_for(gcs, "CAMERA_CAPTURE_STATUS").image_count == 6
        surface.publish(removed(6, []))
        gone = wait_for(gcs, "STATUSTEXT", cond=lambda m: m.text.startswith("Summary -#6"))
        assert gone is not None
    finally:
        gcs.close()
        surface.stop()
        link.stop()



def test_a_resumed_summary_is_served_but_not_counted_or_announced_again():
    link = companion_link(free_udp_port())
    try:
        surface = Downlink(link, SurfaceConfig(), image_count=10)  # an earlier run took images 0-9
        old = added(8, [8])
        old.frame.raw_image = old.frame.image[:, ::-1].copy()
        old.frame.enhanced, old.frame.raw_score = True, 0.61  # an enhanced copy (ss_e 0.8) of a frame with ss_t 0.61
        surface.publish(old)
        assert surface.captures.image_count == 10 and surface.budget.pending() == 0
        assert surface.tree.read("/summary/8.jpg") and surface.tree.read("/summary/raw/8.jpg")[:2] == b"\xff\xd8"
        assert surface.camera.handle(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, 263, 8))[1].image_index == 8
        surface.publish(added(10, [8, 10]))
        assert surface.captures.image_count == 11
        # the capture and its STATUSTEXT, then the capture status and storage as they are now (on every change)
        assert surface.budget.pending(Priority.THUMBNAIL) > 0 and surface.budget.pending(Priority.STATUS) == 4
        served = {t["image_index"]: t for t in json.loads(surface.tree.read("/summary/index.json"))["summary"]}
        assert (served[8]["score"], served[8]["raw_score"], served[8]["raw"]) == (0.8, 0.61, "/summary/raw/8.jpg")
        assert "raw_score" not in served[10] and "raw" not in served[10]
    finally:
        link.stop()
