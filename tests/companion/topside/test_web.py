"""``merlion surface`` as a real subprocess, fed by a companion over UDP, its page rendered by headless Chromium."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import socket
import urllib.error
import urllib.request

import pytest

from companion.config import SurfaceConfig
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import summary_frame
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.companion.topside.live_page import companion_downlink, page_state, surface_with_page
from tests.conftest import free_udp_port, run_merlion
from tests.waiting import wait_until
from vehicle.camera import status as st

DIVE = "5e1f0c2a"


@pytest.mark.slow
def test_merlion_surface_serves_the_live_summary_to_a_real_browser(tmp_path):
    chromium_or_skip()
    port = free_udp_port()
    out = tmp_path / "gallery"
    # the real companion side, its MAVLink link and Downlink: 10x the default budget, for quick thumbnails
    with surface_with_page(out, port, "--web-host", "127.0.0.1", "--push-timeout", "3", duration=120) as shown, \
            companion_downlink(port, SurfaceConfig(budget_bytes_per_s=20000), dive=DIVE) as surface:
        proc, page_url, web = shown.proc, shown.url, shown.web
        frames = {5: summary_frame(5, depth=21.4, yaw_deg=135, score=0.88),
                  6: summary_frame(6, depth=22.6, yaw_deg=270, score=0.77),
                  7: summary_frame(7, depth=23.0, yaw_deg=10, score=0.66),
                  8: summary_frame(8, depth=24.2, yaw_deg=45, score=0.71)}
        # #6 is an enhanced copy (ss_e 0.77) of a frame that scored 0.59 as captured
        frames[6] = dataclasses.replace(frames[6], enhanced=True, raw_score=0.59, raw_image=frames[6].image[::-1])
        frames[8] = dataclasses.replace(frames[8], pose=dataclasses.replace(frames[8].pose, lat=1.26440,
                                                                             lon=103.82220))
        assert wait_until(lambda: page_state(web)["companion"]["id"] == [1, 100], 15)  # its heartbeat reached the tool
        surface.publish(SummaryEvent("added", frames[5], summary=[5]))
        surface.publish(SummaryEvent("added", frames[6], summary=[5, 6]))
        surface.publish(SummaryEvent("added", frames[7], summary=[5, 6, 7]))
        surface.update_status(fps=4.8, seen_fps=10.0, score=0.66, summary=2, depth_m=23.0)
        surface.publish(SummaryEvent("removed", frames[7], summary=[5, 6]))
        surface.event("Camera lost, retrying", st.WARNING)

        def ready() -> bool:
            s = page_state(web)
            return [f["image_index"] for f in s["summary"]] == [6, 5] and all(
                f["thumbnail"] and f["score"] is not None for f in s["summary"]) and s["summary"][0]["raw_score"]

        assert wait_until(ready, 30), page_state(web)
        # each pushed thumbnail is checked against the companion's file with one CalcFileCRC32
        assert wait_until(lambda: page_state(web)["link"]["verified"] >= 2, 20), page_state(web)["link"]
        assert page_state(web)["link"]["mismatched"] == 0
        with Page(page_url) as page:
            # thumbnails really decode in the browser, newest first, each with its depth tag and dive
            loaded = ("[...document.querySelectorAll('#gallery figure.frame img')]"
                      ".every(i => i.complete && i.naturalWidth > 0)")
            assert page.wait_for(f"document.querySelectorAll('#gallery figure.frame img').length == 2 && {loaded}")
            cards = page.evaluate("[...document.querySelectorAll('#gallery figure.frame')]"
                                  ".map(f => [f.dataset.index, f.innerText])")
            assert [i for i, _ in cards] == ["6", "5"], cards  # newest first, the trimmed #7 gone
            text = dict(cards)
            assert "depth 22.6 m" in text["6"] and "heading 270°" in text["6"] and "score 0.77 (raw 0.59)" in text["6"]
            assert "depth 21.4 m" in text["5"] and "heading 135°" in text["5"] and "score 0.88" in text["5"]
            assert "raw" not in text["5"]  # not enhanced: one score
            assert all(f"dive {DIVE}" in t for t in text.values()), text
            assert page.evaluate("document.querySelector('#gallery img').getAttribute('src')").startswith(
                "files/summary/6.jpg")
            # for a pilot: labels with units, warnings apart from summary news, local time beside UTC
            values = page.wait_for("document.getElementById('values').innerText.includes('B/s')"
                                   " && document.getElementById('values').innerText")
            # frames scored, said beside the camera's rate (never "4.8 fps", which reads as the camera's)
            assert re.search(r"Frames\s+scored 4\.8/s of 10\.0/s seen", values), values
            # the header's score is the frame just scored, said so beside the cards' scores
            assert re.search(r"Latest frame\s+score 0\.66", values) and "Score" not in values, values
            assert re.search(r"Depth\s+23\.0 m", values) and "Seen" not in values, values
            assert re.search(r"Link\s+\d+ B/s", values) and "MRL_" not in values, values
            assert page.wait_for("document.getElementById('warnings').innerText.includes('Camera lost')")
            assert "Summary" not in page.evaluate("document.getElementById('warnings').innerText")
            events = page.evaluate("document.getElementById('events').innerText")
            assert "Summary -#7" in events and "Camera lost" not in events
            assert re.search(r"\d\d:\d\d:\d\d local \(\d\d:\d\d:\d\d UTC\)", text["6"]), text["6"]
            assert "companion: 1/100" in page.evaluate("document.body.innerText")
            # the depth plot marks each summary frame
            assert page.wait_for("document.querySelectorAll('#depth-plot circle.mark').length == 2")
            # click-through: the full frame comes from the vehicle over MAVLink FTP, at its own size
            page.evaluate("document.querySelector('#gallery figure.frame[data-index=\"6\"] img').click()")
            size = page.wait_for("!document.getElementById('viewer').hidden"
                                 " && document.querySelector('#viewer img').naturalWidth > 0"
                                 " && [document.querySelector('#viewer img').naturalWidth,"
                                 " document.querySelector('#viewer img').naturalHeight]", 60)
            assert size == [480, 270], size
            assert (out / "full" / DIVE / "6.jpg").read_bytes() == surface.tree.read("/summary/full/6.jpg")
            page.evaluate("document.getElementById('viewer').click()")
            # a new capture appears on the same page, with no reload (a reload would clear this mark)
            page.evaluate("window.notReloaded = true")
            surface.publish(SummaryEvent("added", frames[8], summary=[5, 6, 8]))
            assert page.wait_for("document.querySelector('#gallery figure.frame[data-index=\"8\"] img') !== null"
                                 " && document.querySelector('#gallery figure.frame img').naturalWidth > 0", 30)
            assert page.evaluate("window.notReloaded === true")
            newest = page.evaluate("document.querySelector('#gallery figure.frame').innerText")
            assert "depth 24.2 m" in newest and "1.26440°N 103.82220°E" in newest, newest
            if os.environ.get("MERLION_SURFACE_SCREENSHOT"):
                page.screenshot(os.environ["MERLION_SURFACE_SCREENSHOT"])
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/files/summary/6.jpg", timeout=5) as r:
            assert r.headers["Content-Type"] == "image/jpeg" and r.read() == surface.tree.read("/summary/6.jpg")
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/files/log.csv", timeout=5) as r:
            assert r.read().startswith(b"event,wall_time,dive,image_index")
        token = page_url.split("token=", 1)[1]
        for bad in ("files/../../etc/passwd", "files/summary/nope.jpg", "files/gallery.json.tmp",
                    "full/6.jpg",  # a full-frame fetch spends link bandwidth: refused without the page's token
                    f"full/7.jpg?token={token}"):  # a frame no longer in the summary: not fetched
            with pytest.raises(urllib.error.HTTPError):
                urllib.request.urlopen(f"http://127.0.0.1:{web}/{bad}", timeout=5)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    assert "3 frames in the summary, 3 with thumbnails" in stdout
    assert json.loads((out / "gallery.json").read_text())["summary"] == [5, 6, 8]
    # the same page, saved in the gallery folder, opens from disk with no server
    with Page((out / "index.html").as_uri()) as page:
        assert page.wait_for("document.querySelectorAll('#gallery figure.frame img').length == 3 && [...document"
                             ".querySelectorAll('#gallery figure.frame img')].every(i => i.naturalWidth > 0)")
        assert f"dive {DIVE}" in page.evaluate("document.getElementById('dive').innerText")


def test_bad_arguments_are_one_line_errors_before_anything_is_created(tmp_path):
    out = tmp_path / "never"
    bad = run_merlion("surface", "--connect", "bogus:1", "--out", str(out), timeout=60)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[-1].startswith("merlion: error: mavlink connection")
    assert not out.exists()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:  # e.g. QGroundControl on the port
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        busy = run_merlion("surface", "--connect", f"udpin:127.0.0.1:{port}", "--out", str(out), timeout=60)
    assert busy.returncode == 1 and f"UDP port {port} is taken" in busy.stderr
    assert len(busy.stderr.strip().splitlines()) == 1
