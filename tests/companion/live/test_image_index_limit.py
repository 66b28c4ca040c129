"""Image indices at the end of what MAVLink carries: CAMERA_IMAGE_CAPTURED.image_index is an int32, so 2^31-1 is
the last index there can be. A real `merlion run` on a store two indices short of it, on the simulated vehicle.

Before, the pipeline went on counting: 2147483648 and up could not be packed (a "cannot pack" warning per message,
the surface never heard of those captures) but were stored as frames/2147483648.*; the next start called the
summary damaged, ignored both next-index records and numbered from 2147483648 again, writing over those frames.
Now the last index is handed out, then no new frame enters the summary: one ERROR line, one STATUSTEXT (WARNING),
the status line says so, and a restart resumes the same summary and says so again."""

from __future__ import annotations

import json
from pathlib import Path

from pymavlink import mavutil

from tests.companion.live_harness import Companion, wait_until, write_config

MAX = 2**31 - 1
USED_UP = "Image indices used up"


def _captures(listener, start: int = 0) -> list[int]:
    return [m.image_index for m in listener.messages[start:]
            if m.get_type() == "CAMERA_IMAGE_CAPTURED" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)]


def _used_up(listener, start: int = 0) -> list:
    return [m for m in listener.messages[start:] if m.get_type() == "STATUSTEXT" and USED_UP in str(m.text)]


def _capture_status(gcs, listener) -> int:
    """CAMERA_CAPTURE_STATUS.image_count as the camera component answers a request for it (an int32 too)."""
    start = len(listener.messages)
    nan = float("nan")

    def answered(m) -> bool:
        return m in listener.messages[start:] and m.get_type() == "CAMERA_CAPTURE_STATUS" \
            and (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)
    for _ in range(5):  # a request can be lost on a busy hub; a ground station asks again
        gcs.mav.command_long_send(1, 100, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 262, nan, nan, nan, nan, nan,
                                  nan)
        try:
            return listener.wait_for(answered, 3, "CAMERA_CAPTURE_STATUS").image_count
        except AssertionError:
            continue
    raise AssertionError("no CAMERA_CAPTURE_STATUS")


def test_the_last_int32_index_is_handed_out_and_then_no_frame_enters(tmp_path: Path, dive) -> None:
    hub, gcs, listener = dive
    store = tmp_path / "store"
    store.mkdir()
    (store / "next_index").write_bytes(f"{MAX - 2:>31d}\n".encode())  # the record a long-lived store keeps
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       sampler={"k": 4}, queries={"tau_ss": 0},
                       source={"uri": "synthetic://dive?seconds=60&width=160&height=96"})
    first = Companion("--config", str(cfg))
    first.wait_for("companion running")
    wait_until(lambda: MAX in _captures(listener), 60, "the last index announced")
    said = listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and USED_UP in str(m.text), 60, USED_UP)
    assert said.severity == mavutil.mavlink.MAV_SEVERITY_WARNING  # ridden through: not a pop-up in QGC
    line = first.wait_for("ERROR .*image index 2147483647 was the last")
    assert "move the store aside" in line, line
    assert _capture_status(gcs, listener) == MAX  # 2^31 captures: counted as many as an int32 can say
    assert first.terminate() == 0, first.output
    assert sorted(set(_captures(listener))) == [MAX - 2, MAX - 1, MAX]
    assert "cannot pack" not in first.output
    assert len(_used_up(listener)) == 1 and first.output.count("was the last") == 1, "said once"
    (stopped,) = [x for x in first.output.splitlines() if "companion stopped" in x]
    assert "summary 3/4 (image indices used up)" in stopped, stopped  # the status line says it
    doc = json.loads((store / "summary.json").read_text())
    assert doc["next_image_index"] == MAX + 1 and sorted(doc["summary"]) == [MAX - 2, MAX - 1, MAX]
    assert int((store / "next_index").read_text()) == MAX + 1
    assert {int(p.name.split(".")[0]) for p in (store / "frames").iterdir()} == {MAX - 2, MAX - 1, MAX}

    mark = len(listener.messages)
    second = Companion("--config", str(cfg))
    line = second.wait_for("resuming with")
    assert "3 summary frame(s); next image index 2147483648" in line, line
    second.wait_for("ERROR .*every image index .* is used")
    listener.wait_for(lambda m: m in listener.messages[mark:] and m.get_type() == "STATUSTEXT"
                      and USED_UP in str(m.text), 60, "the second run's STATUSTEXT")
    assert _capture_status(gcs, listener) == MAX
    assert second.terminate() == 0, second.output
    assert "not a list of image indices" not in second.output and "is not one MAVLink" not in second.output
    assert "cannot pack" not in second.output
    assert all(i <= MAX for i in _captures(listener, mark))
    assert sorted(json.loads((store / "summary.json").read_text())["summary"]) == [MAX - 2, MAX - 1, MAX]
