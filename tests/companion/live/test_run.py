"""`merlion run` as a real process: config errors before anything starts, a live run, clean stop, resume."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from companion.config import StoreConfig
from companion.storage.frame_files import read_frame
from companion.storage.store import Store
from tests.companion.live_harness import Companion, store_summary, wait_until, write_config
from tests.conftest import run_merlion


@pytest.mark.parametrize("text, message", [
    ("sampler:\n  kk: 3\n", "sampler.kk: unknown key"),
    ("sampler:\n  k: many\n", "sampler.k: "),
    ("sampler:\n  k: 0\n", "sampler.k: "),
    ("queries:\n  tau_ss: 250\n", "queries.tau_ss: "),
    ("source: [1, 2\n", "line"),
])
def test_bad_config_is_one_line_and_exit_2_before_anything_starts(tmp_path: Path, text: str, message: str) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    store = tmp_path / "store"
    done = run_merlion("run", "--config", str(cfg), "--store", str(store), timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: {cfg}") and message in lines[0], done.stderr
    assert not store.exists(), "nothing may start (not even the store) on a bad config"


def test_missing_config_file_and_bad_environment_value(tmp_path: Path) -> None:
    done = run_merlion("run", "--config", str(tmp_path / "none.yaml"), timeout=60)
    assert done.returncode == 2 and "no such config file" in done.stderr
    done = run_merlion("run", "--store", str(tmp_path / "s"), env={"MERLION__SAMPLER__K": "-4"}, timeout=60)
    assert done.returncode == 2 and "sampler.k" in done.stderr and "MERLION__" in done.stderr


@pytest.mark.parametrize("source, mavlink, message", [
    ("synthetic://dive?seconds=abc", "none", "source 'synthetic://dive?seconds=abc': could not convert string to float"),
    ("synthetic://dive", "bogus:xx", "mavlink connection 'bogus:xx': expected udpin:"),
])
def test_malformed_source_or_connection_is_one_line_and_exit_2_before_anything_starts(
        tmp_path: Path, source: str, mavlink: str, message: str) -> None:
    store = tmp_path / "store"
    done = run_merlion("run", "--source", source, "--store", str(store), "--mavlink", mavlink, "--duration", "30",
                       timeout=60)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: {message}"), done.stderr
    assert not store.exists(), "a malformed source is not retried like an unplugged camera; nothing starts"


def test_run_tags_frames_stores_them_sends_captures_and_stops_cleanly_then_resumes(tmp_path: Path, vehicle) -> None:
    hub, sim, listener = vehicle
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)})
    first = Companion("--config", str(cfg))
    first.wait_for("companion running")
    first.wait_for("autopilot heartbeat up")
    wait_until(lambda: len(store_summary(store).get("summary", [])) >= 4, 90, "four summary frames on disk")
    # frames taken once telemetry flows carry the simulated ArduSub's pose (depth, attitude), never a made-up one
    wait_until(lambda: any(json.loads(p.read_text())["pose"]["depth_m"] is not None
                           for p in (store / "frames").glob("*.json")), 60, "a frame tagged with depth")
    capture = listener.wait_for(lambda m: m.get_type() == "CAMERA_IMAGE_CAPTURED", 60, "CAMERA_IMAGE_CAPTURED")
    assert capture.get_srcComponent() == 100 and capture.file_url.startswith("mftp://")
    assert first.terminate() == 0, first.output
    assert "merlion run: seen" in first.output
    before = store_summary(store)
    for p in (store / "frames").glob("*.json"):
        # stale: nothing made up; else what the vehicle had reported near the frame (attitude at 20 Hz can be
        # there a moment before the first depth sample)
        pose = json.loads(p.read_text())["pose"]
        reported = [pose.get(k) for k in ("depth_m", "roll", "heading_deg")]
        assert (all(v is None for v in reported) if pose["stale"] else any(v is not None for v in reported)), pose
    features = {i: np.load(store / "frames" / f"{i:06d}.npy") for i in before["summary"]}

    # restart on a file that is not there: refused at start (a file does not come back, unlike a camera), and the
    # store is left as it was: nothing lost or renumbered
    missing = tmp_path / "not-there.mp4"
    second = run_merlion("run", "--config", str(cfg), "--source", str(missing), "--duration", "5", timeout=60)
    assert second.returncode == 2, second.stderr
    assert second.stderr.strip() == f"merlion: error: --source {missing}: no such file or folder"
    after = Store(StoreConfig(dir=str(store)))
    assert after.summary == before["summary"]
    assert after.next_image_index == before["next_image_index"]
    for frame in after.resume_state().frames:
        np.testing.assert_array_equal(frame.feature, features[frame.image_index])


def test_selective_enhancement_runs_on_its_worker_and_stores_raw_beside_enhanced(tmp_path: Path) -> None:
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", enhance={"mode": "selective", "method": "classic", "tau_ses": 0.5},
                       mavlink={"connection": None}, store={"dir": str(store)})
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    wait_until(lambda: len(store_summary(store).get("summary", [])) >= 3, 90, "three enhanced summary frames")
    assert companion.terminate() == 0, companion.output
    for index in store_summary(store)["summary"]:
        sidecar = json.loads((store / "frames" / f"{index:06d}.json").read_text())
        assert sidecar["enhanced"] is True and sidecar["raw_file"] == f"frames/{index:06d}.raw.jpg"
        assert (store / sidecar["raw_file"]).is_file()
        # both gates it passed: ss_t of the frame as captured (tau_ss 0.5 here) and ss_e of the copy (tau_ses)
        assert sidecar["raw_score"] > 0.5 and sidecar["score"] > 0.5
        held = read_frame(store, index)
        assert held is not None and held.frame.raw_score == sidecar["raw_score"]
