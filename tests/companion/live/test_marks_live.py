"""The operator teaches the live companion (issue 13 item 3): marks from the surface change what it keeps.

A real `merlion run` plays the survey video (eight rounds, each a little brighter) in a loop (fish and no-fish segments alternate) with the visual
encoder, whose text score is 1.0 for every frame (it has no text tower), behind tau_ss 0.85: before any mark every
frame passes, fish or not. `merlion surface-mark` then marks one stored fish frame "like" and one no-fish frame
"unlike" over MAVLink FTP; the companion acknowledges with a STATUSTEXT and from then on scores by the query and
the examples together: the frames it stores afterwards are fish frames only, with the combined score (below 1.0,
above tau_ss), although the video went through its no-fish segments again. The marks survive a restart and are
cleared by a query upload.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import pytest
from pymavlink import mavutil

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Companion, Listener, ground_ftp, wait_until, write_config
from tests.conftest import run_merlion

TAU = 0.85
ROUNDS = 8
"""Rounds of new footage (74 s): the marks and a whole loop after them fit however slow the machine."""


@pytest.fixture
def survey(shared_data: Path, tmp_path: Path) -> tuple[Path, dict[int, int]]:
    """The survey video, played eight times over in one file, each round a little brighter (as a new pass over a
    site would differ): a summary never holds the same picture twice, so an exact loop would add nothing after
    its first round. Labels: fish_present per frame index of one round."""
    video = shared_data / "survey" / "survey_480x270.mp4"
    labels = shared_data / "survey" / "survey_480x270_labels.csv"
    if not video.exists() or not labels.exists():
        pytest.skip(f"survey video absent: {video}")
    with labels.open(newline="") as fh:
        fish = {int(row["frame_index"]): int(row["fish_present"]) for row in csv.DictReader(fh)}
    cap = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, image = cap.read()
        if not ok:
            break
        frames.append(image)
    cap.release()
    rounds = tmp_path / "survey_rounds.mp4"
    writer = cv2.VideoWriter(str(rounds), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (480, 270))
    for r in range(ROUNDS):
        for image in frames:
            writer.write(cv2.add(image, (4 * r, 4 * r, 4 * r, 0)))
    writer.release()
    assert len(frames) == len(fish)
    return rounds, fish


@pytest.fixture
def hub():
    listener = Listener()
    hub = UdpHub(outputs=[("127.0.0.1", listener.port)]).start()
    yield hub, listener
    hub.stop()
    listener.close()


def _stored(store: Path) -> dict[int, dict]:
    """Every complete frame sidecar in the store, by image index."""
    frames = {}
    for path in (store / "frames").glob("*.json"):
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            continue  # being written
        frames[doc["image_index"]] = doc
    return frames


def _fish(frame: dict, labels: dict[int, int]) -> bool:
    return labels[frame["frame_index"] % len(labels)] == 1


@pytest.mark.slow
def test_marks_from_the_surface_steer_what_the_companion_keeps(tmp_path: Path, survey, hub) -> None:
    video, labels = survey
    hub, listener = hub
    store = tmp_path / "store"
    cfg = write_config(
        tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)}, sampler={"k": 400},
        source={"uri": str(video), "fps": 10, "realtime": True, "loop": True},
        queries={"tau_ss": TAU}, surface={"ftp_writable": True, "push": False, "budget_bytes_per_s": 200000},
    )
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    wait_until(lambda: any(_fish(f, labels) for f in _stored(store).values())
               and any(not _fish(f, labels) for f in _stored(store).values()), 30, "fish and no-fish frames stored")
    before = _stored(store)
    assert {f["score"] for f in before.values()} == {1.0}  # the text score alone: everything passes
    like = next(i for i, f in sorted(before.items()) if _fish(f, labels))
    unlike = next(i for i, f in sorted(before.items()) if not _fish(f, labels))

    marked = run_merlion("surface-mark", "--connect", f"udpout:{hub.host}:{hub.port}", "--like", str(like),
                         "--unlike", str(unlike), "--timeout", "20", timeout=60)
    assert marked.returncode == 0, marked.stdout + marked.stderr
    assert f"like [{like}], unlike [{unlike}]" in marked.stdout
    listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "Marks: 1 like, 1 unlike" in str(m.text), 10,
                      "the companion's acknowledgement")
    companion.wait_for("marks set")
    refused = run_merlion("surface-mark", "--connect", f"udpout:{hub.host}:{hub.port}", "--like", "99999",
                          "--timeout", "20", timeout=60)  # a frame the store never had: the marks stay
    assert refused.returncode != 0
    assert refused.stderr.strip().startswith("merlion: error: the companion refused the marks"), refused.stderr
    listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "Marks refused: image 99999" in str(m.text), 10,
                      "the refusal's reason")
    boundary = max(_stored(store))  # frames stored from here on were scored with the marks
    first_after = max(f["frame_index"] for f in _stored(store).values())

    # wait for a whole loop of the video past the marks: its no-fish segments came round again
    wait_until(lambda: any(f["frame_index"] >= first_after + len(labels) for f in _stored(store).values()), 30,
               "a whole loop of the video after the marks")
    after = [f for i, f in _stored(store).items() if i > boundary + 2]  # a batch in flight may predate the marks
    assert len(after) >= 10
    assert all(_fish(f, labels) for f in after), [(f["frame_index"], f["score"]) for f in after
                                                   if not _fish(f, labels)]
    assert all(TAU < f["score"] < 1.0 for f in after)  # the combined score, not the text score
    saved = json.loads((store / "marks.json").read_text())
    assert (saved["like"], saved["unlike"]) == ([like], [unlike])
    assert companion.terminate() == 0, companion.output

    # a restart re-applies the saved marks; new queries clear them
    again = Companion("--config", str(cfg))
    again.wait_for("restored marks: 1 like, 1 unlike")
    again.wait_for("companion running")
    gcs = mavutil.mavlink_connection(f"udpout:{hub.host}:{hub.port}", source_system=254, source_component=192,
                                     dialect="ardupilotmega")
    try:
        gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        client = ground_ftp(gcs)
        queries = tmp_path / "queries.txt"
        queries.write_text("underwater image of rocks\nunderwater image of open water\n")
        client.cmd_put([str(queries), "/config/queries.txt"])
        client.process_ftp_reply("put", timeout=15)
        again.wait_for("marks cleared with the queries", 20)
    finally:
        gcs.close()
    assert not (store / "marks.json").exists()
    assert again.terminate() == 0, again.output
