"""`merlion extension` as BlueOS runs it: a real process joined to a "BlueOS router" (a UDP hub with the simulated
ArduSub on it), its companion child, its page behind a real nginx at /extensionv2/merlion/, in real headless
Chromium: the full page and Cockpit's widget (in an iframe of Cockpit's default widget size) with decoded
thumbnails, a mark and a stop/start going through the proxy, points of interest sent to Cockpit's iframe API."""

from __future__ import annotations

import base64
import json
import os
import re
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.companion.extension.reverse_proxy import ReverseProxy
from tests.companion.live_harness import simulated_vehicle, wait_until, write_config
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.conftest import REPO, run_merlion, stop_process
from tests.waiting import wait_until as poll_until
from vehicle.sim.dive_profile import DEFAULT_PROFILE, compile_profile

WIDGET_SIZE = (384, 389)
"""Cockpit gives a new widget 20% x 36% of its view: on a 1920x1080 screen, 384 x 389 pixels."""
SOURCE = "synthetic://dive?seconds=600&width=320&height=192"
HOST_PAGE = """<!doctype html><meta charset="utf-8"><title>Cockpit stand-in</title>
<script>
  window.cockpitMessages = [];
  addEventListener("message", (e) => { if (e.data && String(e.data.type).startsWith("cockpit:")) cockpitMessages.push(e.data); });
</script>
<iframe id="widget" src="/extensionv2/merlion/widget" style="width:WIDTHpx;height:HEIGHTpx;border:0"></iframe>
""".replace("WIDTH", str(WIDGET_SIZE[0])).replace("HEIGHT", str(WIDGET_SIZE[1]))


def get(url: str, headers: dict | None = None) -> tuple[int, bytes, dict]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read(), dict(r.headers)
    except urllib.error.HTTPError as err:
        return err.code, err.read(), dict(err.headers)


def post(url: str, body: dict, headers: dict) -> tuple[int, dict]:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json", **headers})
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.load(r)
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read() or b"{}")


def landed(page: Page, expression: str, timeout: float = 30.0):
    """``page.wait_for`` across the entry page's hop to ``?token=`` (an evaluation cut short by it is retried)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return page.wait_for(expression, max(1.0, deadline - time.monotonic()))
        except AssertionError as err:
            if "navigated" not in str(err) or time.monotonic() > deadline:
                raise
            time.sleep(0.2)


@pytest.fixture(scope="module")
def extension(tmp_path_factory):
    """The extension process on a free port, its companion running against the simulated dive; and nginx."""
    chromium_or_skip()
    root = tmp_path_factory.mktemp("extension")
    cfg = write_config(root / "merlion.yaml", sampler={"k": 4}, queries={"tau_ss": 0.3},
                       surface={"budget_bytes_per_s": 40000, "status_hz": 2, "ftp_writable": True})
    placed = compile_profile({**DEFAULT_PROFILE, "origin": {**DEFAULT_PROFILE["origin"], "after_s": 0}})
    with (open(root / "extension.log", "wb") as ext_log,
          simulated_vehicle(profile=placed) as (router, _sim, _listener)):  # an EKF origin from the start
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion", "extension", "--data", str(root / "data"), "--port", "0",
             "--host", "127.0.0.1", "--router", f"127.0.0.1:{router.port}", "--config", str(cfg),
             "--source", SOURCE], cwd=REPO, stdout=subprocess.PIPE, stderr=ext_log,
            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        proxy = None
        try:
            line = proc.stdout.readline()
            match = re.search(r"page at http://127\.0\.0\.1:(\d+)/", line)
            assert match, f"no page line: {line!r} (exit {proc.poll()})"
            port = int(match.group(1))
            proxy = ReverseProxy(root / "nginx", port)
            (proxy.cockpit / "host.html").write_text(HOST_PAGE)
            yield port, proxy, root / "data"
        finally:
            if proxy is not None:
                proxy.close()
            stop_process(proc, 60)


def test_register_service_and_cockpit_extras_over_http(extension):
    port, proxy, _ = extension
    direct = f"http://127.0.0.1:{port}"
    status, body, headers = get(f"{direct}/register_service")
    assert status == 200 and headers["Content-Type"] == "application/json"
    service = json.loads(body)
    for key in ("name", "description", "icon", "company", "version", "webpage", "api"):
        assert isinstance(service[key], str), key
    assert service["works_in_relative_paths"] is True and service["extras"]["cockpit"] == "/cockpit_extras.json"
    status, body, _ = get(f"{direct}/")  # what BlueOS's helper checks: 200 with a <title>
    assert status == 200 and re.search(rb"<title>[^<]+</title>", body)

    status, body, _ = get(f"{proxy.base}/extensionv2/merlion/cockpit_extras.json")  # as Cockpit reads it
    extras = json.loads(body)
    assert status == 200 and extras["targetSystem"] == "Cockpit" and extras["targetCockpitApiVersion"] == "1.0.0"
    (widget,) = extras["widgets"]
    assert widget["iframeUrl"] == widget["iframe_url"] == "/widget" and widget["useExtensionPathAsBaseUrl"] is True
    assert widget["iframeIcon"] and get(f"{proxy.base}/extensionv2/merlion{widget['iframeIcon']}")[0] == 200
    ids = {a["id"] for a in extras["actions"]}
    assert {"merlion-start", "merlion-stop", "merlion-like-newest", "merlion-unlike-newest", "merlion-topic-main"} <= ids
    for action in extras["actions"]:
        config = action["config"]
        assert action["type"] == "http-request" and config["method"] == "POST" and config["urlParams"] == {}
        assert config["url"].startswith("http://{{ vehicle-address }}/extensionv2/merlion/api/")
        json.loads(config["body"])
    suggestions = extras["joystickSuggestions"][0]["buttonMappingSuggestions"]
    assert {s["actionId"] for s in suggestions} <= ids


def test_page_and_widget_through_the_proxy_in_chromium(extension, tmp_path):
    port, proxy, data = extension
    base = f"{proxy.base}/extensionv2/merlion/"
    wait_until(lambda: sum(1 for f in json.loads(get(base + "api/state")[1])["summary"] if f["thumbnail"]) >= 2,
               180, "two summary frames with thumbnails, through the proxy")

    with Page(base) as page:  # what BlueOS's sidebar opens
        assert landed(page, "location.search.includes('token=') && location.pathname") == "/extensionv2/merlion/"
        # wait for the count asserted, not for the first image: the second may decode a moment later
        decoded = page.wait_for("(n => n >= 2 && n)(Array.from(document.querySelectorAll('#gallery img'))"
                                ".filter((i) => i.complete && i.naturalWidth > 0).length)", 60)
        assert decoded >= 2, "thumbnails decoded in the full page behind the proxy"

    with Page(f"{proxy.base}/cockpit/host.html") as cockpit:
        frame = "(document.getElementById('widget') || {}).contentDocument"
        decoded = landed(cockpit, f"{frame} && {frame}.body && (n => n >= 2 && n)(Array.from("
                                   f"{frame}.querySelectorAll('.frame img'))"
                                   ".filter((i) => i.complete && i.naturalWidth > 0).length)", 60)
        assert decoded >= 2, "thumbnails decoded in the widget"
        assert cockpit.evaluate(f"{frame}.location.pathname") == "/extensionv2/merlion/widget"
        assert cockpit.wait_for(f"{frame}.getElementById('light').classList.contains('ok')", 30)
        size = cockpit.evaluate(f"[{frame}.documentElement.clientWidth, {frame}.documentElement.clientHeight]")
        assert tuple(size) == WIDGET_SIZE
        overflow = cockpit.evaluate(f"{frame}.documentElement.scrollHeight <= {frame}.documentElement.clientHeight")
        assert overflow, "the widget fits Cockpit's default size without scrolling"
        for _attempt in range(3):  # the newest frame may leave the summary while the mark is on its way: try again
            newest = cockpit.evaluate(f"Number({frame}.querySelector('.frame').dataset.index)")
            cockpit.evaluate(f"{frame}.querySelector('.frame button.like').click()")  # "more like this", via nginx
            if cockpit.wait_for(f"{frame}.querySelector('.frame[data-index=\"{newest}\"] button.like.on') !== null",
                                30):
                break
        else:
            stub = get(base)[1].decode()
            token = re.search(r"token=([\w-]+)", stub).group(1)
            held = json.loads(get(base + "api/state")[1])["summary"][0]["image_index"]
            raise AssertionError(str(post(base + "api/mark", {"index": held, "kind": "like"},
                                          {"Origin": proxy.base, "X-Merlion-Token": token})))
        state = json.loads(get(base + "api/state")[1])
        assert newest in state["marks"]["like"]
        pois = cockpit.wait_for("cockpitMessages.filter((m) => m.type === 'cockpit:addPointOfInterest')", 30)
        assert pois, "a point of interest for each frame whose position is known"
        placed = {f["image_index"]: f for f in state["summary"] if f["lat"] is not None}
        for message in pois:
            poi = message["poi"]
            index = int(poi["id"].rsplit("-", 1)[1])
            assert index in placed or index not in {f["image_index"] for f in state["summary"]}
            assert abs(poi["latitude"] - 1.2644) < 0.01 and abs(poi["longitude"] - 103.8222) < 0.01

    shot = Path(os.environ.get("MERLION_WIDGET_SCREENSHOT") or tmp_path / "widget.png")
    with Page(base + "widget") as widget:
        widget.call("Emulation.setDeviceMetricsOverride", width=WIDGET_SIZE[0], height=WIDGET_SIZE[1],
                    deviceScaleFactor=1, mobile=False)
        landed(widget, "Array.from(document.querySelectorAll('.frame img'))"
                        ".filter((i) => i.complete && i.naturalWidth > 0).length >= 2", 60)
        data_png = widget.call("Page.captureScreenshot", format="png")["data"]
    shot.write_bytes(base64.b64decode(data_png))
    assert struct.unpack(">II", shot.read_bytes()[16:24]) == WIDGET_SIZE


def test_switch_topic_through_the_proxy(extension):
    _, proxy, _ = extension
    base = f"{proxy.base}/extensionv2/merlion/"
    token = re.search(r"token=([\w-]+)", get(base)[1].decode()).group(1)
    headers = {"Origin": proxy.base, "X-Merlion-Token": token}
    status, answer = post(base + "api/topic", {"topic": "coral"}, headers)
    assert status == 400 and "not one of main" in answer["error"]
    status, answer = post(base + "api/topic", {"topic": "main"}, headers)  # Cockpit's "follow main" action
    assert status == 200, answer
    assert answer["topic"] == "main" and any(s.startswith(("Queries set", "Topics set")) for s in answer["status"])


def _logs(data: Path) -> str:
    """The tails of the companion's and the extension's logs, for a failure's message."""
    tails = []
    for path in (data / "companion.log", data.parent / "extension.log"):
        text = path.read_text(errors="replace") if path.exists() else "(none)"
        tails.append(f"{path.name}: ...{text[-1500:]}")
    return "\n".join(tails)


def test_stop_and_start_the_companion_through_the_proxy(extension):
    _, proxy, data = extension
    base = f"{proxy.base}/extensionv2/merlion/"
    started = poll_until(lambda: "companion running" in (data / "companion.log").read_text(errors="replace"), 120)
    assert started, f"the companion's start never reached its log\n{_logs(data)}"  # stopping it mid-import tells nothing
    stub = get(base)[1].decode()
    token = re.search(r"token=([\w-]+)", stub).group(1)
    origin = {"Origin": proxy.base, "X-Merlion-Token": token}
    status, answer = post(base + "api/companion", {"run": "yes"}, origin)
    assert status == 400 and "true or false" in answer["error"]
    assert post(base + "api/companion", {"run": False}, {"Origin": "http://evil.example"})[0] == 403
    status, answer = post(base + "api/companion", {"run": False}, origin)
    assert status == 200 and answer == {"companion_running": False}
    assert json.loads(get(base + "api/extension")[1])["companion_running"] is False
    assert "merlion run: seen" in (data / "companion.log").read_text(), _logs(data)  # stopped cleanly, store saved
    status, answer = post(base + "api/companion", {"run": True}, origin)
    assert status == 200 and answer == {"companion_running": True}
    wait_until(lambda: "resuming with" in (data / "companion.log").read_text(), 120, "the companion resumed")


def test_bad_arguments_are_one_line_and_exit_2(tmp_path):
    done = run_merlion("extension", "--data", str(tmp_path / "d"), "--router", "nowhere", "--duration", "1")
    assert done.returncode == 2 and done.stderr.strip() == \
        "merlion: error: --router 'nowhere': expected HOST:PORT (e.g. 127.0.0.1:14660)"
    bad = tmp_path / "bad.yaml"
    bad.write_text("sampler:\n  k: 0\n")
    done = run_merlion("extension", "--data", str(tmp_path / "d"), "--config", str(bad), "--duration", "1")
    assert done.returncode == 2 and done.stderr.strip().startswith(f"merlion: error: {bad}")
