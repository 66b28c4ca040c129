"""Dive logs without Ray: streamed poses against the written profile, log matching, mapping file, manifest keys."""

from __future__ import annotations

import json
import math

import pytest

from companion.archive.dives import find_sources, make_dives
from companion.archive.log_match import match_logs, read_mapping
from companion.archive.manifest import Manifest, dive_key
from companion.archive.tlog_stream import log_span, poses_at
from companion.config import load_config
from companion.errors import MerlionError
from tests.companion.archive.clips import cut_clips
from tests.companion.archive.dive_log import depth_at, write_dive_log, yaw_at
from tests.conftest import shared_file
from vehicle.settings import TelemetryConfig

T0 = 1_700_000_000.0


@pytest.fixture
def dive_log(tmp_path):
    return write_dive_log(tmp_path / "dive.tlog", T0, 60.0)


def test_poses_follow_the_written_profile_and_are_stale_outside_the_log(dive_log):
    times = [T0 + 41.37, T0 + 3.05, T0 + 59.5, T0 + 75.0, T0 - 20.0]  # out of order on purpose
    poses = poses_at(dive_log, times, TelemetryConfig())
    assert [p.time for p in poses] == pytest.approx(times)
    for t, pose in zip(times[:3], poses[:3], strict=True):
        assert not pose.stale and pose.depth_source == "global_position_int"
        assert pose.depth_m == pytest.approx(depth_at(t, T0), abs=0.1)
        assert math.radians(pose.heading_deg) == pytest.approx(yaw_at(t, T0), abs=0.01)
        assert pose.roll == pytest.approx(0.01, abs=1e-3) and pose.pitch == pytest.approx(-0.02, abs=1e-3)
    assert poses[3].stale and poses[3].depth_m is None  # after the log: nothing made up
    assert poses[4].stale and poses[4].depth_m is None


def test_log_span_and_a_file_that_is_no_log(dive_log, tmp_path):
    first, last = log_span(dive_log)
    assert first == pytest.approx(T0) and last == pytest.approx(T0 + 60.0, abs=0.02)
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(b"not a log at all" * 100)
    with pytest.raises(MerlionError, match="junk.tlog: not a MAVLink telemetry log"):
        log_span(junk)


def test_dives_match_the_log_that_covers_them_by_file_time_or_mapping(tmp_path):
    survey = shared_file("survey/survey_480x270.mp4")
    inside, outside = cut_clips(survey, tmp_path, 2, 2.0, [T0 + 20.0, T0 + 500.0])
    log_a = write_dive_log(tmp_path / "a.tlog", T0, 60.0)
    log_b = write_dive_log(tmp_path / "b.tlog", T0 + 1000.0, 60.0)
    dives = make_dives([inside, outside])
    assert dives[0].start_time == pytest.approx(T0 + 20.0) and dives[0].duration_s == pytest.approx(2.0)
    by_time = match_logs(dives, [log_a, log_b])
    assert by_time[0].tlog == log_a and by_time[1].tlog is None
    mapping_file = tmp_path / "mapping.csv"
    mapping_file.write_text(f"video,tlog,offset_s\n{outside.name},b.tlog,12.5\n")
    mapped = match_logs(dives, [log_a, log_b], read_mapping(mapping_file))
    assert mapped[1].tlog == log_b and mapped[1].dive.start_time == pytest.approx(T0 + 1012.5)
    mapping_file.write_text(f"video,tlog,offset_s\n{outside.name},b.tlog,soon\n")
    with pytest.raises(MerlionError, match="line 2: offset_s 'soon' is not a number"):
        read_mapping(mapping_file)


def test_manifest_key_changes_with_a_setting_and_survives_a_reload(tmp_path, dive_log):
    video = cut_clips(shared_file("survey/survey_480x270.mp4"), tmp_path, 1, 1.0, [T0 + 5.0])[0]
    cfg = load_config(None, overrides={"encoder": {"name": "visual"}})
    key = dive_key(video, dive_log, T0 + 5.0, cfg)
    assert key == dive_key(video, dive_log, T0 + 5.0, cfg)
    assert key != dive_key(video, dive_log, T0 + 5.0, load_config(None, overrides={
        "encoder": {"name": "visual"}, "sampler": {"k": 9}}))
    assert key != dive_key(video, dive_log, T0 + 6.0, cfg)  # another start time: other tags
    out = tmp_path / "campaign"
    (out / "dive01").mkdir(parents=True)
    (out / "dive01" / "summary.json").write_text("{}")
    Manifest.load(out).mark_finished("dive01", key, {"frames_seen": 3})
    again = Manifest.load(out)
    assert again.is_done("dive01", key) and not again.is_done("dive01", "other")
    (out / "manifest.json").write_text(json.dumps({"version": 99}))
    with pytest.raises(MerlionError, match="manifest version 99"):
        Manifest.load(out)


def test_dive_names_are_unique_and_never_the_campaign_folders_own(tmp_path):
    clip = cut_clips(shared_file("survey/survey_480x270.mp4"), tmp_path, 1, 1.0, [T0])[0]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    same_a, same_b, report = tmp_path / "a" / "dive.mp4", tmp_path / "b" / "dive.mp4", tmp_path / "report.mp4"
    for p in (same_a, same_b, report):
        p.write_bytes(clip.read_bytes())
    names = [d.name for d in make_dives(find_sources([tmp_path / "a", tmp_path / "b", report]))]
    assert len(set(names)) == 3 and all(n.startswith(("dive-", "report-")) for n in names)
    notes = tmp_path / "notes.txt"
    notes.write_text("not footage")
    with pytest.raises(MerlionError, match="notes.txt: not a video"):
        find_sources([notes])
