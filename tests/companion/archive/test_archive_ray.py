"""`merlion archive` on a local two-node Ray cluster: summaries identical to `merlion summarize`, depth from the
log, a run killed mid-campaign resumes without redoing finished dives, the campaign report and frame index."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from companion.config import load_config
from companion.vision.summarize import summarize
from tests.companion.archive.clips import cut_clips
from tests.companion.archive.dive_log import depth_at, write_dive_log
from tests.conftest import REPO, run_merlion, shared_file
from tests.waiting import wait_until

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402

# one xdist worker runs every test that starts Ray (see test_archive_cli.py)
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray")]

T0 = 1_700_000_000.0
CLIPS = 6
KILL_TRIES = 3
OPTIONS = ["--encoder", "visual", "--fps", "4", "-k", "3"]


@pytest.fixture(scope="module")
def cluster():
    """Two Ray nodes of one CPU each on this machine (Ray's own test cluster), not connected to this process."""
    c = Cluster(initialize_head=True, connect=False,
                head_node_args={"num_cpus": 1, "object_store_memory": 80 * 1024 * 1024, "include_dashboard": False})
    c.add_node(num_cpus=1, object_store_memory=80 * 1024 * 1024)
    c.wait_for_nodes()
    yield c
    c.shutdown()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    root = tmp_path_factory.mktemp("campaign")
    videos = root / "videos"
    videos.mkdir()
    starts = [T0 + 10.0 + 10.0 * i for i in range(CLIPS)]
    clips = cut_clips(shared_file("survey/survey_480x270.mp4"), videos, CLIPS, 3.0, starts)
    logs = root / "logs"
    logs.mkdir()
    write_dive_log(logs / "dive.tlog", T0, 10.0 * CLIPS + 20.0)
    return root, clips, starts


def archive_cmd(address: str, videos: Path, logs: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "companion", "archive", str(videos), "--tlog", str(logs), "--out", str(out),
            "--address", address, *OPTIONS]


def finished(out: Path) -> dict:
    try:
        return json.loads((out / "manifest.json").read_text())["finished"]
    except (OSError, ValueError, KeyError):
        return {}


def _start_and_kill(address: str, root: Path, out: Path) -> dict:
    """Start the campaign into ``out``, kill -9 its driver as soon as a dive is recorded; the dives recorded."""
    first = subprocess.Popen(archive_cmd(address, root / "videos", root / "logs", out), cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ))
    try:
        assert wait_until(lambda: len(finished(out)) >= 1 or first.poll() is not None, timeout=60), \
            "no dive finished"
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=10)
    finally:
        if first.poll() is None:
            first.kill()
        first.communicate()
    done = finished(out)
    assert done, f"the driver died before any dive finished (exit {first.returncode})"
    return done


def _kill_after_the_first_dive(address: str, root: Path) -> tuple[Path, dict]:
    """A campaign folder whose driver was killed with some dives finished and some not.

    A dive here takes a tenth of a second, so on a loaded machine the whole campaign can end before the kill lands
    (seen once in CI), which proves nothing about resuming: then the campaign is started again in a fresh folder.
    """
    for attempt in range(KILL_TRIES):
        out = root / f"out{attempt}"
        done = _start_and_kill(address, root, out)
        if len(done) < CLIPS:
            return out, done
    pytest.fail(f"the kill came too late to prove anything in {KILL_TRIES} tries: every dive had finished")


def _loads_once_per_worker(runs: list[list[dict]]) -> None:
    """In each run every worker process loads the encoder at most once, and some worker summarized two dives."""
    reused = False
    for entries in runs:
        pids = [m["worker_pid"] for m in entries]
        loads = [m["worker_pid"] for m in entries if m["encoder_loaded"]]
        assert len(loads) == len(set(loads)) and len(loads) <= len(set(pids)), entries
        reused |= len(set(pids)) < len(entries)
    assert reused, runs  # 6 dives over 2 one-CPU workers in two runs: one run has 3 or more


def test_killed_campaign_resumes_and_matches_summarize(cluster, campaign):
    root, clips, starts = campaign
    # 1. start the campaign, kill the driver as soon as the first dive is recorded as finished
    out, done_before = _kill_after_the_first_dive(cluster.address, root)
    stamps = {name: (out / name / "summary.json").stat().st_mtime_ns for name in done_before}

    # 2. the rerun skips exactly the finished dives and does the rest
    proc = subprocess.run(archive_cmd(cluster.address, root / "videos", root / "logs", out), cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"{CLIPS - len(done_before)} dives summarized, {len(done_before)} already done (skipped)" in proc.stdout
    for name, stamp in stamps.items():
        assert (out / name / "summary.json").stat().st_mtime_ns == stamp  # not redone
    manifest = finished(out)
    assert sorted(manifest) == [c.stem for c in clips]
    rerun = [manifest[n] for n in manifest if n not in done_before]
    assert len(rerun) == CLIPS - len(done_before)
    _loads_once_per_worker([list(done_before.values()), rerun])

    # 3. every dive: byte-identical to summarize on the same file, depth tags from the log within 0.1 m
    cli_ref = root / "ref_cli"
    ref = run_merlion("summarize", str(clips[0]), "--out", str(cli_ref), *OPTIONS)
    assert ref.returncode == 0, ref.stderr
    cfg = load_config(None, overrides={"encoder": {"name": "visual"}, "source": {"fps": 4}, "sampler": {"k": 3}})
    for i, clip in enumerate(clips):
        dive = out / clip.stem
        if i == 0:
            expected = cli_ref
        else:
            expected = root / f"ref_{clip.stem}"
            summarize(cfg.model_copy(update={"source": cfg.source.model_copy(update={"uri": str(clip)})}),
                      expected, progress=False)
        assert (dive / "summary.json").read_bytes() == (expected / "summary.json").read_bytes()
        assert (dive / "contact_sheet.jpg").read_bytes() == (expected / "contact_sheet.jpg").read_bytes()
        names = sorted(p.name for p in (expected / "frames").iterdir())
        assert names and sorted(p.name for p in (dive / "frames").iterdir()) == names
        for n in names:
            assert (dive / "frames" / n).read_bytes() == (expected / "frames" / n).read_bytes()
        tags = json.loads((dive / "tags.json").read_text())
        assert tags["tlog"].endswith("dive.tlog") and tags["start_time"] == pytest.approx(starts[i])
        summary = json.loads((dive / "summary.json").read_text())
        assert [f["index"] for f in tags["frames"]] == [f["index"] for f in summary["frames"]]
        for f in tags["frames"]:
            assert not f["pose"]["stale"]
            assert f["pose"]["depth_m"] == pytest.approx(depth_at(starts[i] + f["time_s"], T0), abs=0.1)

    # 4. the campaign report and the index of every summary frame
    rows = list(csv.DictReader((out / "index.csv").read_text().splitlines()))
    assert len(rows) == sum(len(json.loads((out / c.stem / "summary.json").read_text())["frames"]) for c in clips)
    for row in rows:
        assert (out / row["file"]).is_file() and row["topic"] == "main"
        assert row["query"] == "underwater image with fish"
        t = starts[int(row["dive"][-2:]) - 1] + float(row["time_s"])
        assert float(row["depth_m"]) == pytest.approx(depth_at(t, T0), abs=0.1)
    index = json.loads((out / "index.json").read_text())
    assert [(r["dive"], r["file"]) for r in index] == [(r["dive"], r["file"]) for r in rows]
    page = (out / "index.html").read_text()
    for clip in clips:
        assert f"{clip.stem}/contact_sheet.jpg" in page
        assert (out / "report" / f"{clip.stem}_depth.png").stat().st_size > 1000
        assert (out / "report" / f"{clip.stem}_scores.png").stat().st_size > 1000


def test_a_bad_video_fails_alone_and_a_changed_setting_redoes_the_dives(cluster, campaign, tmp_path):
    root, clips, _ = campaign
    videos = tmp_path / "videos"
    videos.mkdir()
    good = videos / clips[0].name
    good.write_bytes(clips[0].read_bytes())
    os.utime(good, (clips[0].stat().st_mtime,) * 2)
    (videos / "broken.mp4").write_bytes(b"\x00" * 4096)
    out = tmp_path / "out"
    proc = subprocess.run(archive_cmd(cluster.address, videos, root / "logs", out), cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "broken: FAILED: " in proc.stdout and "1 dives summarized, 0 already done (skipped), 1 failed" in proc.stdout
    manifest = json.loads((out / "manifest.json").read_text())
    assert list(manifest["finished"]) == [good.stem] and "broken.mp4" in manifest["failed"]["broken"]["error"]
    changed = archive_cmd(cluster.address, good, root / "logs", out) + ["-k", "2"]
    proc = subprocess.run(changed, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "1 dives summarized, 0 already done (skipped)" in proc.stdout
    assert len(json.loads((out / good.stem / "summary.json").read_text())["frames"]) <= 2
