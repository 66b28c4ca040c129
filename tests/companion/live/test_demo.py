"""`merlion demo`, the README's first command, end to end: three programs on loopback, a summary at the surface."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import pytest

from tests.conftest import run_merlion
from tests.waiting import wait_until


@pytest.mark.slow
def test_short_demo_leaves_gallery_store_and_report(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    # the packaged encoder (what a fresh machine has), a quick dive, and a low threshold so a short run fills
    # the summary whatever the machine's speed
    done = run_merlion("demo", "--duration", "10", "--out", str(out), "--source", "synthetic://dive?seconds=2",
                       "--tau-ss", "0.02", "--encoder", "imagenet", timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "merlion demo: done" in done.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["frames_seen"] > 0 and report["frames_passed"] > 0
    assert report["summary"] and report["bytes_sent"] > 0
    # the store holds the summary on board ...
    store = json.loads((out / "store" / "summary.json").read_text())
    assert store["summary"] == report["summary"]
    for index in store["summary"]:
        assert (out / "store" / "frames" / f"{index:06d}.jpg").is_file()
    # ... and the surface tool received it over MAVLink: captures with depth, thumbnails on disk
    gallery = json.loads((out / "surface" / "gallery.json").read_text())
    # the surface mirrors the vehicle's summary exactly (the demo waits, bounded, for the last trims in flight;
    # a trim that arrives while an index.json is on its way must not be undone by that older index)
    assert gallery["summary"] == sorted(store["summary"])
    assert report["surface_summary"] == len(store["summary"])
    with_thumbs = [c for c in gallery["captures"] if c["in_summary"] and c["thumbnail"]]
    assert with_thumbs and report["thumbnails_delivered"] >= len(with_thumbs)
    for cap in with_thumbs:
        assert (out / "surface" / cap["thumbnail"]).stat().st_size > 0
    assert any(c["depth_m"] is not None for c in gallery["captures"])
    assert f"thumbnails         {report['thumbnails_delivered']} delivered" in done.stdout
    # the demo shows itself: the live page's URL first, a page that opens from disk, a contact sheet last
    first = done.stdout.splitlines()[0]
    assert re.fullmatch(r"merlion demo: surface page at http://127\.0\.0\.1:\d+/\S* \(live while the demo runs\)",
                        first), first
    assert report["web_url"] in first
    assert (out / "surface" / "index.html").is_file() and (out / "surface" / "state.js").is_file()
    assert '<script src="app.js">' in (out / "surface" / "index.html").read_text()
    sheet = out / "contact_sheet.jpg"
    assert done.stdout.strip().splitlines()[-1] == f"  contact sheet      {sheet}"
    image = cv2.imread(str(sheet))
    assert image is not None and image.shape[1] >= 320


def test_demo_refuses_a_missing_source(tmp_path: Path) -> None:
    done = run_merlion("demo", "--duration", "5", "--out", str(tmp_path / "d"), "--source",
                       str(tmp_path / "nope.mp4"), timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == f"merlion: error: --source {tmp_path / 'nope.mp4'}: no such file or folder"


def test_ctrl_c_ends_the_demo_early_with_its_report(tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys

    from tests.conftest import REPO

    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "companion", "demo", "--duration", "600", "--out", str(out),
                             "--encoder", "visual"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        for line in proc.stdout:
            if line.startswith("merlion demo: companion running"):
                break
        # everything is up once the store holds a frame (sooner than the first progress line, 10 s in)
        assert wait_until(lambda: (out / "store" / "changes.jsonl").is_file(), 60), "no frame stored"
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=120)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, rest
    assert "merlion demo: done" in rest
    report = json.loads((out / "report.json").read_text())
    assert report["duration_s"] < 600 and report["frames_seen"] > 0


def test_demo_refuses_a_web_port_out_of_range(tmp_path: Path) -> None:
    done = run_merlion("demo", "--web", "70000", "--out", str(tmp_path / "d"), timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == "merlion: error: --web 70000: not a port (0-65535; 0 picks a free one)"
    assert not (tmp_path / "d").exists()
