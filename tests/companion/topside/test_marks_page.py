"""The page's "more like this" / "not this": a real `merlion surface` uploads /config/marks.json to a Downlink.

The tool's own FTP client writes the file (CreateFile, WriteFile, TerminateSession) over UDP; the companion side
is the real Downlink with a writable tree. A POST needs the run's token; a refused upload is the page's error.
Where Chromium is installed, the buttons on the cards are clicked as an operator would.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.error
import urllib.request

import pytest

from companion.config import MavlinkConfig, SurfaceConfig
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import summary_frame
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.conftest import REPO, free_udp_port, run_merlion
from tests.waiting import wait_until
from vehicle.camera.downlink import Downlink
from vehicle.link.connection import MavLink


def _post(url: str, body: dict, token: str | None) -> tuple[int, dict]:
    headers = {"Content-Type": "application/json"}
    if token is not None:
        headers["X-Merlion-Token"] = token
    req = urllib.request.Request(url, data=json.dumps(body).encode(), headers=headers, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.load(r)
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read() or b"{}")


def _state(port: int) -> dict:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/state", timeout=5) as r:
        return json.load(r)


@pytest.fixture
def surface_and_companion(tmp_path):
    """`merlion surface --web 0` and a companion Downlink holding frames 5 and 6; yields (page url, web port,
    marks the companion accepted)."""
    port = free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion", "surface", "--connect", f"udpin:127.0.0.1:{port}", "--out",
         str(tmp_path / "gallery"), "--web", "0", "--duration", "90"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
    )
    link = surface = None
    try:
        line = proc.stdout.readline()
        match = re.search(r"live page at (http://127\.0\.0\.1:(\d+)/\?token=(\S+))", line)
        assert match, line
        link = MavLink(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100), name="companion")
        link.start()
        surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, ftp_writable=True))
        accepted: list[tuple[list[int], list[int]]] = []

        def on_marks(like: list[int], unlike: list[int]) -> None:
            if any(i not in (5, 6) for i in like + unlike):
                raise ValueError("not in the store")
            accepted.append((like, unlike))

        surface.on_marks_changed(on_marks)
        surface.start()
        web = int(match.group(2))
        assert wait_until(lambda: _state(web)["companion"]["id"] == [1, 100], 15)
        surface.publish(SummaryEvent("added", summary_frame(5), summary=[5]))
        surface.publish(SummaryEvent("added", summary_frame(6), summary=[5, 6]))
        assert wait_until(lambda: [f["image_index"] for f in _state(web)["summary"]] == [6, 5], 30)
        yield match.group(1), web, match.group(3), accepted
    finally:
        if surface is not None:
            surface.stop()
        if link is not None:
            link.stop()
        proc.terminate()
        proc.wait(30)


def test_a_post_marks_frames_on_the_companion_and_needs_the_token(surface_and_companion):
    _, web, token, accepted = surface_and_companion
    url = f"http://127.0.0.1:{web}/api/mark"
    status, answer = _post(url, {"index": 6, "kind": "like"}, None)
    assert status == 403 and accepted == []
    status, answer = _post(url, {"index": 6, "kind": "like"}, token)
    assert status == 200, answer
    assert answer["marks"] == {"like": [6], "unlike": []}
    status, answer = _post(url, {"index": 5, "kind": "unlike"}, token)
    assert status == 200, answer
    assert accepted == [([6], []), ([6], [5])]  # each mark sends the whole set
    status, answer = _post(url, {"index": 99, "kind": "like"}, token)  # the companion refuses it
    assert status == 400 and "marks not set: refused" in answer["error"], answer
    status, answer = _post(url, {"index": 5, "kind": "maybe"}, token)
    assert status == 400 and "expected like, unlike or none" in answer["error"]
    assert _state(web)["marks"] == {"like": [6], "unlike": [5]}
    status, answer = _post(url, {"index": 6, "kind": "none"}, token)
    assert status == 200 and accepted[-1] == ([], [5])


def test_the_cards_buttons_mark_a_frame(surface_and_companion):
    chromium_or_skip()
    page_url, web, _, accepted = surface_and_companion
    with Page(page_url) as page:
        button = "document.querySelector('#gallery figure.frame[data-index=\"{i}\"] button.mark.{kind}')"
        assert page.wait_for(button.format(i=6, kind="like") + " !== null")
        page.evaluate(button.format(i=6, kind="like") + ".click()")
        assert wait_until(lambda: accepted == [([6], [])], 30), accepted
        assert page.wait_for(button.format(i=6, kind="like") + ".classList.contains('on')", 10)
        page.evaluate(button.format(i=5, kind="unlike") + ".click()")
        assert wait_until(lambda: accepted[-1:] == [([6], [5])], 30), accepted
        assert page.wait_for(button.format(i=5, kind="unlike") + ".classList.contains('on')", 10)


@pytest.mark.parametrize("args, says", [
    ((), "give --like INDEX and/or --unlike INDEX, or --clear"),
    (("--clear", "--like", "3"), "--clear takes no --like/--unlike"),
    (("--like", "-3"), "image index -3 is negative"),
    (("--like", "4", "--unlike", "4"), "image 4 is both like and unlike"),
])
def test_surface_mark_bad_arguments_are_one_line_errors(args, says):
    done = run_merlion("surface-mark", "--connect", f"udpout:127.0.0.1:{free_udp_port()}", *args, timeout=60)
    assert done.returncode != 0
    assert done.stderr.strip().splitlines() == [done.stderr.strip()] and says in done.stderr, done.stderr


def test_surface_mark_with_no_companion_says_so():
    done = run_merlion("surface-mark", "--connect", f"udpout:127.0.0.1:{free_udp_port()}", "--like", "3",
                       "--timeout", "2", timeout=60)
    assert done.returncode != 0
    assert done.stderr.strip().startswith("merlion: error: no answer from the companion 1:100"), done.stderr
