"""The page's "more like this" / "not this": a real `merlion surface` uploads /config/marks.json to a Downlink.

The tool's own FTP client writes the file (CreateFile, WriteFile, TerminateSession) over UDP; the companion side
is the real Downlink with a writable tree. A POST needs the run's token; a refused upload is the page's error.
Where Chromium is installed, the buttons on the cards are clicked as an operator would.
"""

from __future__ import annotations

import json
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


@pytest.fixture
def surface_and_companion(tmp_path):
    """`merlion surface --web 0` and a companion Downlink holding frames 5 and 6; yields (page url, web port,
    marks the companion accepted)."""
    port = free_udp_port()
    with surface_with_page(tmp_path / "gallery", port) as shown, \
            companion_downlink(port, SurfaceConfig(budget_bytes_per_s=20000, ftp_writable=True),
                               start=False) as surface:
        accepted: list[tuple[list[int], list[int]]] = []

        def on_marks(like: list[int], unlike: list[int]) -> None:
            if any(i not in (5, 6) for i in like + unlike):
                raise ValueError("not in the store")
            accepted.append((like, unlike))

        surface.on_marks_changed(on_marks)
        surface.start()
        web = shown.web
        assert wait_until(lambda: page_state(web)["companion"]["id"] == [1, 100], 15)
        surface.publish(SummaryEvent("added", summary_frame(5), summary=[5]))
        surface.publish(SummaryEvent("added", summary_frame(6), summary=[5, 6]))
        assert wait_until(lambda: [f["image_index"] for f in page_state(web)["summary"]] == [6, 5], 30)
        yield shown.url, web, shown.token, accepted


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
    assert page_state(web)["marks"] == {"like": [6], "unlike": [5]}
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
