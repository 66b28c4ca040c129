"""Settings never lost, MERL_ENHANCE in every enhance.mode, tau_ss = 0 as "no gate" (issue 12 items 2 and 4).

Through the real command line: a params.json or store written by a newer merlion stops `merlion run` with one
`merlion: error:` line naming the file and both versions, and leaves the file byte for byte as it was; an older
params.json is migrated and its values applied. From a ground station: MERL_ENHANCE switches enhancement in
mode ``always`` and is refused with a STATUSTEXT saying why in mode ``none``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from pymavlink import mavutil

from companion.storage.params_file import FILE_VERSION
from companion.storage.store import FORMAT_VERSION
from tests.companion.live_harness import Companion, set_param, store_summary, wait_until, write_config
from tests.conftest import run_merlion


@pytest.mark.parametrize("name, current", [("params.json", FILE_VERSION), ("summary.json", FORMAT_VERSION)])
def test_a_file_from_a_newer_version_stops_the_start_and_is_left_untouched(tmp_path: Path, name: str,
                                                                           current: int) -> None:
    store = tmp_path / "store"
    store.mkdir()
    path = store / name
    path.write_text(json.dumps({"version": current + 1, "written_by": "99.0", "params": {"MERL_K": 3},
                                "summary": [], "next_image_index": 5}, indent=3))
    before = path.read_bytes()
    done = run_merlion("run", "--store", str(store), "--mavlink", "none", "--duration", "20", timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: {path}: written by merlion 99.0"), done.stderr
    assert f"format version {current + 1}" in lines[0] and f"format version {current} at most" in lines[0]
    assert path.read_bytes() == before
    assert sorted(p.name for p in store.iterdir()) == [name], "nothing else may be written to the store"


def test_an_older_params_file_is_migrated_and_its_values_applied(tmp_path: Path, dive) -> None:  # noqa: F811
    hub, gcs, listener = dive
    store = tmp_path / "store"
    store.mkdir()
    (store / "params.json").write_text(json.dumps({"version": 1, "params": {"MERL_K": 3, "MERL_TAU_SS": 0.0}}))
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       sampler={"k": 8})
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    wait_until(lambda: len(store_summary(store).get("summary", [])) >= 3, 60, "a full summary of 3")
    gcs.mav.param_request_read_send(1, 100, b"MERL_K", -1)
    assert listener.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MERL_K", 10,
                             "MERL_K").param_value == 3
    set_param(gcs, listener, "MERL_K", 4, integer=True)  # the next save writes the current version
    wait_until(lambda: json.loads((store / "params.json").read_text())["version"] == FILE_VERSION, 10,
               "params.json saved in the current version")
    assert companion.terminate() == 0, companion.output
    saved = json.loads((store / "params.json").read_text())
    assert saved["params"]["MERL_K"] == 4 and saved["params"]["MERL_TAU_SS"] == 0.0
    assert max(len(json.loads(line)["summary"]) for line in (store / "changes.jsonl").read_text().splitlines()) <= 4


def test_merl_enhance_is_refused_with_a_reason_when_no_enhancer_is_loaded(tmp_path: Path, dive) -> None:  # noqa: F811
    hub, gcs, listener = dive
    store = tmp_path / "s"
    store.mkdir()
    # saved while enhance.mode was selective; the mode is none now
    (store / "params.json").write_text(json.dumps({"version": FILE_VERSION, "params": {"MERL_ENHANCE": 1}}))
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       enhance={"mode": "none"})
    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    assert json.loads((store / "params.json").read_text())["params"]["MERL_ENHANCE"] == 0, "saved as in force"
    set_param(gcs, listener, "MERL_ENHANCE", 1, integer=True, expect=0)  # a refused value is not taken
    text = listener.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "MERL_ENHANCE" in m.text, 10, "the reason")
    assert text.text == "MERL_ENHANCE refused: enhance.mode is none"
    assert text.severity == mavutil.mavlink.MAV_SEVERITY_WARNING
    assert companion.terminate() == 0, companion.output


def test_merl_enhance_switches_enhancement_in_mode_always(tmp_path: Path, dive) -> None:  # noqa: F811
    hub, gcs, listener = dive
    store = tmp_path / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(store)},
                       enhance={"mode": "always", "method": "classic"}, queries={"tau_ss": 0},
                       source={"uri": "synthetic://dive?seconds=40&width=160&height=96"}, sampler={"k": 40})

    def newest_enhanced() -> bool | None:
        changes = store / "changes.jsonl"
        if not changes.exists():
            return None
        added = [json.loads(line) for line in changes.read_text().splitlines()]
        added = [e["image_index"] for e in added if e["kind"] == "added"]
        if not added:
            return None
        return json.loads((store / "frames" / f"{added[-1]:06d}.json").read_text())["enhanced"]

    companion = Companion("--config", str(cfg))
    companion.wait_for("companion running")
    wait_until(lambda: newest_enhanced() is True, 60, "an enhanced frame stored")
    set_param(gcs, listener, "MERL_ENHANCE", 0, integer=True)
    wait_until(lambda: newest_enhanced() is False, 60, "a frame stored as captured")
    set_param(gcs, listener, "MERL_ENHANCE", 1, integer=True)
    wait_until(lambda: newest_enhanced() is True, 60, "an enhanced frame again")
    assert companion.terminate() == 0, companion.output
    assert "refused" not in companion.output


def test_threshold_zero_keeps_every_frame_offline(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(3)
    for i in range(5):
        cv2.imwrite(str(folder / f"{i:03d}.png"), rng.integers(0, 255, (64, 96, 3), dtype=np.uint8))
    done = run_merlion("summarize", str(folder), "--encoder", "visual", "--threshold", "0",
                       "--out", str(tmp_path / "out"), timeout=120)
    assert done.returncode == 0, done.stderr
    assert "summary frames from 5 images (5 passed the query)" in done.stdout, done.stdout
