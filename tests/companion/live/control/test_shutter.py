"""The pilot's shutter in the live companion, in process over real UDP: no frame yet, then a kept frame that a
restart puts back outside the sampler."""

from __future__ import annotations

from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import build_config
from companion.live.companion import LiveCompanion
from tests.waiting import wait_until


def _config(store: Path, hub_url: str, uri: str):
    return build_config({
        "source": {"uri": uri, "fps": 10, "realtime": True, "loop": True, "retry_initial_s": 0.2,
                   "retry_max_s": 0.5},
        "encoder": {"name": "visual"}, "sampler": {"k": 1},
        "mavlink": {"connection": hub_url}, "store": {"dir": str(store)},
    })


def _press(gcs, listener) -> int:
    """IMAGE_START_CAPTURE as QGroundControl sends it; the camera's ACK result (sent again until one comes)."""
    for _ in range(5):
        start = len(listener.messages)
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 1, 0, 0, 0, 0)
        try:
            ack = listener.wait_for(lambda m, start=start: m.get_type() == "COMMAND_ACK"
                                    and m.get_srcComponent() == 100 and m.command == mav.MAV_CMD_IMAGE_START_CAPTURE
                                    and m in listener.messages[start:], 5, "shutter ACK")
            return ack.result
        except AssertionError:
            continue
    raise AssertionError("the shutter was never acknowledged")


def test_no_frame_yet_is_a_temporary_refusal_said_on_the_surface(tmp_path: Path, dive) -> None:
    hub, gcs, listener = dive
    app = LiveCompanion(_config(tmp_path / "store", hub.url, "rtsp://127.0.0.1:9/no-camera"))
    app.start()
    try:
        assert _press(gcs, listener) == mav.MAV_RESULT_TEMPORARILY_REJECTED  # QGroundControl retries, then resets
        assert wait_until(lambda: "Shutter: no camera frame yet" in listener.texts(), 10)
        assert app.surface.camera.capture_status().image_status == 0 and app.store.summary == []
    finally:
        app.stop()


def test_a_pressed_frame_is_stored_as_the_pilots_and_comes_back_after_a_restart(tmp_path: Path, dive) -> None:
    hub, gcs, listener = dive
    store = tmp_path / "store"
    uri = "synthetic://dive?seconds=2&width=160&height=96"
    app = LiveCompanion(_config(store, hub.url, uri))
    app.start()
    try:
        assert wait_until(lambda: app.capture is not None and app.capture.latest is not None, 30)
        assert _press(gcs, listener) == mav.MAV_RESULT_ACCEPTED
        assert wait_until(lambda: app.on_shutter.taken, 30)
        (key,) = app.on_shutter.taken
        assert wait_until(lambda: app.surface.camera.capture_status().image_status == 0, 30)
        assert app.store.sidecar(key)["pilot"] is True and key in app.store.summary
        assert any(key in t.pilot and key not in t.sampler.keys for t in app.pipeline.topics)
        app.on_shutter.max_frames = 1  # (200 in service) never trimmed, so never more than that many
        assert _press(gcs, listener) == mav.MAV_RESULT_TEMPORARILY_REJECTED
        assert wait_until(lambda: "Shutter: 1 pilot frames held" in listener.texts(), 10)
        assert app.on_shutter.taken == [key]
    finally:
        app.stop()
    again = LiveCompanion(_config(store, hub.url, uri))
    again.start()
    try:
        assert key in again.store.summary
        assert any(key in t.pilot and key not in t.sampler.keys for t in again.pipeline.topics)
    finally:
        again.stop()
