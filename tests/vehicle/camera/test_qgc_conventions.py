"""What QGroundControl's own code requires of a MAVLink camera, checked on our real messages over loopback.

From QGroundControl's source (src/Camera/QGCCameraManager.cc, CameraDiscoveryStateMachine.cc,
VehicleCameraControl.cc, src/Vehicle/Vehicle.cc):
- a camera is a component of the vehicle's system id with a compid in MAV_COMP_ID_CAMERA..CAMERA6 (older
  releases also take MAV_TYPE_CAMERA with MAV_AUTOPILOT_INVALID); it is dropped after 5 s without a heartbeat;
- discovery alternates MAV_CMD_REQUEST_MESSAGE(CAMERA_INFORMATION) and MAV_CMD_REQUEST_CAMERA_INFORMATION(1); a
  COMMAND_ACK other than ACCEPTED counts as a failure, success is the CAMERA_INFORMATION itself;
- vendor_name and model_name are read as C strings (a NUL must end them inside their 32 bytes); an empty
  cam_definition_uri makes a "basic" camera, which is then asked for its settings and storage (it must answer,
  or QGroundControl keeps retrying); HAS_VIDEO_STREAM makes it ask for streams;
- each CAMERA_IMAGE_CAPTURED with capture_result == 1 adds a map marker at lat/1e7, lon/1e7, with no 0/0 check
  (Vehicle.cc ``_handleCameraImageCaptured``): a capture without a position must carry capture_result 0;
- STATUSTEXT at ERROR or worse pops up (CRITICAL or worse is spoken): only real faults may use them.
"""

from __future__ import annotations

import ast

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import SurfaceConfig
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.conftest import REPO, free_udp_port
from tests.vehicle.surface_env import companion_link, ground_station, scene, wait_for
from vehicle.autopilot.pose import Pose
from vehicle.camera import status as st
from vehicle.camera.component import firmware_version_of
from vehicle.camera.downlink import Downlink

NAN = float("nan")
POPS_UP = mav.MAV_SEVERITY_ERROR
REAL_FAULTS: dict[str, int] = {}
"""STATUSTEXT call sites (``file: text``) allowed at ERROR or worse; none today: every fault the companion reports
(link lost, camera lost, refused uploads) is one the vehicle rides through, so it is a WARNING."""


@pytest.fixture
def qgc():
    """Our camera component on a real link (system 1, component 100) and a ground station facing it."""
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=40000, push=False), version="0.4.2")
    gcs = ground_station(port)
    assert wait_for(gcs, "HEARTBEAT") is not None
    surface.start()
    yield surface, gcs
    gcs.close()
    surface.stop()
    link.stop()


def command(gcs, cmd: int, p1: float = NAN, p2: float = NAN) -> None:
    gcs.mav.command_long_send(1, 100, cmd, 0, p1, p2, NAN, NAN, NAN, NAN, NAN)


def ack_for(gcs, cmd: int):
    return wait_for(gcs, "COMMAND_ACK", cond=lambda m: m.command == cmd)


def c_string(field) -> str:
    raw = bytes(field) if not isinstance(field, (str, bytes)) else (field.encode() if isinstance(field, str)
                                                                    else field)
    raw = raw.ljust(32, b"\0")
    assert b"\0" in raw[:32], "QGroundControl reads this field as a C string: it needs its NUL"
    return raw[:raw.index(b"\0")].decode("ascii")


def test_qgc_finds_the_camera_and_accepts_its_information_both_ways(qgc):
    _, gcs = qgc
    beats = [wait_for(gcs, "HEARTBEAT", cond=lambda m: m.get_srcComponent() == 100) for _ in range(3)]
    for hb in beats:
        assert hb is not None and hb.get_srcSystem() == 1  # the vehicle's own system id
        assert mav.MAV_COMP_ID_CAMERA <= hb.get_srcComponent() <= mav.MAV_COMP_ID_CAMERA6
        assert (hb.type, hb.autopilot) == (mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID)
    assert max(b._timestamp for b in beats) - min(b._timestamp for b in beats) < 2 * 5.0  # never 5 s apart

    infos = []
    for cmd, p1 in ((mav.MAV_CMD_REQUEST_MESSAGE, 259), (mav.MAV_CMD_REQUEST_CAMERA_INFORMATION, 1)):
        command(gcs, cmd, p1)
        ack = ack_for(gcs, cmd)
        assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED and ack.target_system == 255
        info = wait_for(gcs, "CAMERA_INFORMATION", cond=lambda m: m.get_srcComponent() == 100)
        assert info is not None
        infos.append(info)
    for info in infos:
        assert c_string(info.vendor_name) == "MERLION" and c_string(info.model_name)
        assert c_string(info.cam_definition_uri) == ""  # a basic camera: no definition file to fetch
        # a shutter is offered only with a companion to take the captures (tests/companion/live/test_qgc_shutter.py):
        # QGroundControl shows its button for this flag, and a press nobody takes would hang it
        assert not info.flags & mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        assert not info.flags & mav.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM  # no stream to ask for
        assert info.firmware_version == firmware_version_of("0.4.2") == 0 | 4 << 8 | 2 << 16
    # what QGroundControl asks a basic camera next is answered (not left to its retries)
    for cmd in (mav.MAV_CMD_REQUEST_CAMERA_SETTINGS, mav.MAV_CMD_REQUEST_STORAGE_INFORMATION,
                mav.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS):
        command(gcs, cmd, 1)
        ack = ack_for(gcs, cmd)
        assert ack is not None and ack.result in (mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_UNSUPPORTED)


def frame(index: int, pose: Pose | None) -> SummaryFrame:
    return SummaryFrame(image_index=index, frame_index=index, time_s=float(index), capture_time=1_700_000_000.0 + index,
                        score=0.7, image=scene(index, 160, 96), feature=np.ones(8, np.float32), pose=pose)


def pose(lat=None, lon=None, *, stale=False) -> Pose:
    return Pose(time=1_700_000_000.0, age_s=0.1, stale=stale, depth_m=8.0, heading_deg=30.0, lat=lat, lon=lon)


def test_captures_put_a_map_marker_only_where_the_position_is_valid(qgc):
    surface, gcs = qgc
    cases = {
        0: (pose(1.2501, 103.8002), (12_501_000, 1_038_002_000)),  # an EKF origin: a real position
        1: (pose(), (0, 0)),  # no position source (no DVL/USBL): no marker at all
        2: (pose(1.25, None), (0, 0)),  # half a position is no position
        3: (pose(1.25, 103.8, stale=True), (0, 0)),  # telemetry lost: the old position is not this frame's
        4: (pose(NAN, NAN), (0, 0)),
        5: (None, (0, 0)),
        6: (pose(0.0, 0.0), (0, 0)),  # a pose that says 0/0 (a tool that did not filter it): still no marker
        7: (pose(4e-8, -4e-8), (0, 0)),  # rounds to 0/0 on the wire (1e-7 degree units): no marker there either
    }
    held: list[int] = []
    for index, (p, _) in cases.items():
        held.append(index)
        surface.publish(SummaryEvent("added", frame(index, p), summary=list(held)))
    got = {}
    while len(got) < len(cases):
        msg = wait_for(gcs, "CAMERA_IMAGE_CAPTURED", timeout=10)
        assert msg is not None, f"captures seen: {sorted(got)}"
        got[msg.image_index] = msg
    markers = []
    for index, (_, (lat, lon)) in cases.items():
        msg = got[index]
        assert msg.capture_result == (1 if (lat, lon) != (0, 0) else 0) and msg.get_srcComponent() == 100
        assert (msg.lat, msg.lon) == (lat, lon)
        if msg.capture_result == 1:  # QGroundControl's rule, exactly: no 0/0 check of its own
            markers.append((msg.lat / 1e7, msg.lon / 1e7))
    assert markers == [(1.2501, 103.8002)]
    assert got[1].relative_alt == -8000 and got[5].relative_alt == 0  # depth still rides along without position


# ---- every STATUSTEXT the companion can send, and its severity ------------------------------------------------

SEVERITY_NAMES = {name: getattr(mav, f"MAV_SEVERITY_{name}") for name in
                  ("EMERGENCY", "ALERT", "CRITICAL", "ERROR", "WARNING", "NOTICE", "INFO", "DEBUG")}


def _severity_of(node: ast.expr) -> int | None:
    name = node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else None
    if name is None:
        return node.value if isinstance(node, ast.Constant) and isinstance(node.value, int) else None
    name = name.removeprefix("MAV_SEVERITY_")
    return SEVERITY_NAMES.get(name)


def _helper_severities(call: ast.Call) -> list[tuple[str, int]] | None:
    """``*st.link_text(alive)`` and friends: every line the helper can return, for each argument it may get."""
    func = call.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
    helper = getattr(st, name, None)
    if helper is None:
        return None
    if name == "started_text":
        return [helper("x.y.z")]
    return [helper(True), helper(False)]


def statustext_sites() -> list[tuple[str, str, int]]:
    """(file:line, text, severity) of every STATUSTEXT the companion and its vehicle side can send (the simulated
    ArduSub excluded: it speaks for the autopilot, not for us)."""
    sites = []
    files = [p for p in sorted((REPO / "companion").rglob("*.py")) + sorted((REPO / "vehicle").rglob("*.py"))
             if "sim" not in p.relative_to(REPO).parts]
    for path in files:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        # a line kept in a module constant (NO_POSITION_TEXT = "...") is audited by its words
        constants = {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
                     and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)
                     for t in n.targets if isinstance(t, ast.Name)}

        def text_of(arg: ast.expr, constants: dict[str, str] = constants) -> str:
            return constants.get(arg.id, arg.id) if isinstance(arg, ast.Name) else ast.unparse(arg)

        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            where = f"{path.relative_to(REPO)}:{node.lineno}"
            if name == "event" and len(node.args) > 1 and isinstance(node.args[1], ast.Name) \
                    and node.args[1].id == "severity":
                continue  # a forwarder (ControlContext.say): its callers' lines are audited where they are written
            if name in ("event", "notify", "say") and node.args and isinstance(node.args[0], ast.Starred):
                lines = _helper_severities(node.args[0].value)
                assert lines is not None, f"{where}: a STATUSTEXT whose severity this audit cannot read"
                sites.extend((where, text, sev) for text, sev in lines)
            elif (name in ("event", "say") and isinstance(func, ast.Attribute)) or \
                    (name == "notify" and path.name.startswith("telemetry")):
                sev_node = node.args[1] if len(node.args) > 1 else next(
                    (k.value for k in node.keywords if k.arg == "severity"), None)
                severity = st.INFO if sev_node is None else _severity_of(sev_node)
                assert severity is not None, f"{where}: a STATUSTEXT whose severity this audit cannot read"
                sites.append((where, text_of(node.args[0]), severity))
            elif name in ("MAVLink_statustext_message", "statustext_send") and path.name != "status.py":
                severity = _severity_of(node.args[0])
                assert severity is not None, f"{where}: a STATUSTEXT whose severity this audit cannot read"
                sites.append((where, text_of(node.args[1]), severity))
    return sites


def test_no_routine_statustext_pops_up_in_qgc():
    sites = statustext_sites()
    texts = " | ".join(text for _, text, _ in sites)
    # the audit sees the lines it must (if it stopped finding calls it would pass on nothing)
    for expected in ("Autopilot link lost", "Camera lost, retrying", "started", "added_text", "trimmed_text",
                     "Queries refused", "No position source", "Source ended"):
        assert expected in texts, f"{expected!r} not found among {texts}"
    popping = [(where, text, sev) for where, text, sev in sites
               if sev <= POPS_UP and REAL_FAULTS.get(f"{where.split(':')[0]}: {text}") != sev]
    assert popping == [], "only real faults may pop up in QGroundControl"
    warnings = {text for _, text, sev in sites if sev == mav.MAV_SEVERITY_WARNING}
    assert "Autopilot link lost" in warnings and "Camera lost, retrying" in warnings
    routine = [text for _, text, sev in sites if sev >= mav.MAV_SEVERITY_INFO]
    assert any("added_text" in t for t in routine) and "Autopilot link back" in routine


def test_the_lines_arrive_with_those_severities(qgc):
    surface, gcs = qgc
    started = wait_for(gcs, "STATUSTEXT", cond=lambda m: "started" in m.text)
    assert started.severity == mav.MAV_SEVERITY_INFO
    surface.publish(SummaryEvent("added", frame(7, pose()), summary=[7]))
    surface.publish(SummaryEvent("removed", frame(7, pose()), summary=[]))
    surface.event(*st.link_text(False))
    surface.event(*st.link_text(True))
    seen = {}
    for _ in range(4):
        msg = wait_for(gcs, "STATUSTEXT", timeout=10, cond=lambda m: "started" not in m.text)
        assert msg is not None, seen
        seen[msg.text] = msg.severity
    assert seen["Autopilot link lost"] == mav.MAV_SEVERITY_WARNING
    assert seen["Autopilot link back"] == mav.MAV_SEVERITY_INFO
    summary = {t: s for t, s in seen.items() if t.startswith("Summary")}
    assert len(summary) == 2 and set(summary.values()) == {mav.MAV_SEVERITY_INFO}
    assert all(s > POPS_UP for s in seen.values())


def test_version_packing_follows_the_mavlink_spec():
    assert firmware_version_of("1.2.3") == 1 | 2 << 8 | 3 << 16
    assert firmware_version_of("0.1.0+g1234") == 1 << 8
    assert firmware_version_of("dev") == 0 and firmware_version_of("") == 0
