"""The proof of issue 11: the real companion with the simulator and independent ground stations at once.

Real processes on loopback, joined by a UDP hub as BlueOS' router joins them: ``merlion run`` on a short video,
``merlion sim-vehicle`` sending ArduSub heartbeats and telemetry, two pymavlink ``mavftp`` ground stations (each
its own process, ``vehicle/sim/gcs_load.py``) listing and downloading /summary and /summary/full, asking the
server's CRC-32 of each file, setting a parameter and uploading a queries file the companion refuses; MAVSDK
lists and downloads too where it is installed. ``MERLION_STRESS_S`` sets the duration (default 5 s: five or so
rounds of each client's lists, downloads, CRCs, parameter write and refused upload; the issue's 60 s run is
``MERLION_STRESS_S=60``).
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest

from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import Companion, store_summary, wait_until, write_clip, write_config
from tests.conftest import stop_process
from vehicle.sim.gcs_load import run_client

DURATION_S = float(os.environ.get("MERLION_STRESS_S", "5"))
PARAM = ("MERL_TAU_SES", 0.3, 0.6)


def _mavsdk_client(port: int, duration_s: float, out: dict) -> None:
    """MAVSDK as a third, independent implementation: list /summary and download the index and thumbnails."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.ftp import Ftp, FtpResult

    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    out.update(lists=0, downloads=0, failures=[])
    try:
        sdk.add_any_connection(f"udpout://127.0.0.1:{port}")
        end = time.monotonic() + 15
        while not sdk.get_systems() and time.monotonic() < end:
            time.sleep(0.1)
        ftp = Ftp(sdk.get_systems()[0])
        ftp.set_target_compid(100)
        folder = Path(out["folder"])
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            names = [e.name for e in ftp.list_directory("/summary").entries]
            out["lists"] += 1
            for name in ["index.json", *[n for n in names if n.endswith(".jpg")][:2]]:
                done = threading.Event()
                results = []

                def progress(result, _p, _u, results=results, done=done):
                    results.append(result)
                    if result.name != "NEXT":
                        done.set()

                ftp.download_async(f"/summary/{name}", str(folder), True, progress)
                if not done.wait(20) or results[-1] != FtpResult.SUCCESS:
                    out["failures"].append(name)
                    continue
                out["downloads"] += 1
                if name.endswith(".jpg") and not ftp.are_files_identical(str(folder / name), f"/summary/{name}"):
                    out["failures"].append(f"{name} differs")
    except Exception as err:  # reported by the test's assertion
        out["failures"].append(repr(err))
    finally:
        sdk.destroy()


@pytest.mark.slow
def test_companion_serves_many_ground_stations_at_once(tmp_path: Path) -> None:
    hub = UdpHub().start()
    sim = subprocess.Popen([sys.executable, "-m", "companion", "-q", "sim-vehicle", "--connect", hub.url,
                            "--duration", str(DURATION_S + 120)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    clip = write_clip(tmp_path / "dive.avi", frames=20)
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url},
                       store={"dir": str(tmp_path / "store")},
                       surface={"ftp_writable": True, "budget_bytes_per_s": 40000})
    companion = Companion("--config", str(cfg), "--source", str(clip))
    ctx = multiprocessing.get_context("spawn")
    results = ctx.Queue()
    gcs = [ctx.Process(target=run_client, args=(hub.url, 200 + i, DURATION_S, PARAM, i, results), daemon=True)
           for i in range(2)]
    sdk_out: dict = {"folder": str(tmp_path)}
    sdk_thread = None
    try:
        companion.wait_for("ended after", timeout=120)  # the summary is final: downloads compare against it
        wait_until(lambda: store_summary(tmp_path / "store")["summary"], 30, "a stored summary")
        mark = companion.mark()
        for p in gcs:
            p.start()
        try:
            import mavsdk  # noqa: F401

            sdk_thread = threading.Thread(target=_mavsdk_client, args=(hub.port, DURATION_S, sdk_out), daemon=True)
            sdk_thread.start()
        except ImportError:
            pass
        got = [results.get(timeout=DURATION_S + 120) for _ in gcs]
        if sdk_thread is not None:
            sdk_thread.join(DURATION_S + 60)
        log = companion.output[mark:]
        assert companion.terminate() == 0, companion.output
    finally:
        for p in gcs:
            if p.is_alive():
                p.kill()
        companion.kill()
        sim.terminate()
        sim.wait(10)
        hub.stop()

    for r in got:  # shown with -s: the figures of a run
        print(f"client {r.get('system_id')}: {r.get('received')} packets, {r.get('corrupted')} corrupted, "
              f"{r.get('lists')} lists, {sum(len(c) for c in r.get('downloads', {}).values())} downloads, "
              f"{r.get('params_set')} PARAM_SET, uploads {dict(Counter(r.get('refused_upload', [])))}")
    print(f"MAVSDK: {sdk_out}")
    for r in got:
        assert "error" not in r, r
        assert r["corrupted"] == 0, f"client {r['system_id']}: {r['corrupted']} packets failed CRC/length"
        assert r["received"] > 100 and r["lists"] > 0 and r["list_failures"] == 0, r
        assert r["download_failures"] == 0 and r["downloads"], r
        # every copy of a file equals what the companion holds (its own CRC-32 of its bytes, asked on the link)
        for path, copies in r["downloads"].items():
            assert path in r["server_crc"], path
            assert all(c[1] == r["server_crc"][path] for c in copies), (path, copies)
        assert r["refused_upload"] and all(a.startswith("nak") for a in r["refused_upload"]), r["refused_upload"]
        assert r["params_set"] and r["param_echoes"] == r["params_set"], r
    # a full frame downloaded is byte for byte the on-board store's file (for the frames the store still holds)
    from vehicle.protocol.ftp import crc32_ardupilot

    compared = 0
    for r in got:
        for path, copies in r["downloads"].items():
            if path.startswith("/summary/full/"):
                stored = tmp_path / "store" / "frames" / f"{int(Path(path).stem):06d}.jpg"
                if stored.is_file():
                    compared += 1
                    assert all(c == [stored.stat().st_size, crc32_ardupilot(stored.read_bytes())] for c in copies), path
    assert compared > 0, "no full frame was compared with the store"
    # the two stations saw the same bytes for the same file
    first, second = (r["downloads"] for r in got)
    for path in set(first) & set(second):
        assert first[path][0] == second[path][0], path
    if sdk_thread is not None:
        assert sdk_out["downloads"] and not sdk_out["failures"], sdk_out
    assert "autopilot heartbeat lost" not in log, log
    assert "queries set" not in log  # the refused uploads changed nothing


@pytest.mark.skipif(sys.platform != "linux", reason="loopback processes")
def test_mavproxy_ftp_lists_and_fetches_the_index(tmp_path: Path) -> None:
    """MAVProxy's own ftp module as a third independent client."""
    pytest.importorskip("MAVProxy", reason="MAVProxy is not installed (pip install mavproxy)")
    from tests.conftest import free_udp_port
    from tests.vehicle.surface_env import added, companion_link
    from vehicle.camera.downlink import Downlink
    from vehicle.settings import SurfaceConfig

    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=40000, push=False))
    surface.start()
    for i in (3, 4):
        surface.publish(added(i, [3, 4][: i - 2]))
    local = tmp_path / "index.json"
    out = tmp_path / "mavproxy.out"
    with out.open("wb") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpout:127.0.0.1:{port}", "--source-system=250",
             "--target-system=1", "--target-component=100", "--daemon", "--non-interactive",
             "--default-modules=ftp", f"--cmd=ftp list /summary; ftp get /summary/index.json {local}"],
            stdout=sink, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=tmp_path)
    try:
        wait_until(lambda: local.exists() and local.stat().st_size == len(surface.tree.read("/summary/index.json")),
                   40, "MAVProxy's download of /summary/index.json")
        assert local.read_bytes() == surface.tree.read("/summary/index.json")
        listing = out.read_text(errors="replace")
        assert "index.json" in listing and "3.jpg" in listing, listing
    finally:
        stop_process(proc, 10)
        surface.stop()
        link.stop()
