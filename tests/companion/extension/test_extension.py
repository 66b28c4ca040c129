"""`merlion extension` as BlueOS and Cockpit serve it: a real process joined to a "BlueOS router" (a UDP hub with
the simulated ArduSub on it), its companion child, its page behind a real nginx configured as BlueOS configures
its own (``reverse_proxy.BlueOSProxy``: the server-level ``Access-Control-Allow-Origin *``, the helper's location
block with ``Host $host``, port 80 and another port), in real headless Chromium that reaches the vehicle by
BlueOS's names: the sidebar link, the widget in a Cockpit stand-in, every Cockpit action run as Cockpit runs it
(also after the extension restarts), and a stranger's page that can read what BlueOS's proxy lets it read but can
neither change anything, nor read the state, nor frame the widget. ``test_blueos_facts_hold`` holds the extension
to BlueOS's path rule, ports, names and headers (``blueos_facts``, read from BlueOS's source)."""

from __future__ import annotations

import base64
import http.client
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from companion import __version__
from companion.extension.metadata import BASE, NAME, PORT, TITLE, cockpit_extras, register_service
from companion.extension.vehicle_guard import vehicle_names
from tests.companion.extension import blueos_facts as facts
from tests.companion.extension.reverse_proxy import FRONTEND_PAGE, BlueOSProxy
from tests.companion.live_harness import simulated_vehicle, wait_until, write_config
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.conftest import REPO, run_merlion, stop_process
from tests.waiting import wait_until as poll_until
from vehicle.sim.dive_profile import DEFAULT_PROFILE, compile_profile

WIDGET_SIZE = (384, 389)
"""Cockpit gives a new widget 20% x 36% of its view: on a 1920x1080 screen, 384 x 389 pixels."""
SOURCE = "synthetic://dive?seconds=600&width=320&height=192"
VEHICLE = "blueos-wifi.local"
"""How the pilot's browser reaches the vehicle here (BlueOS's beacon name of wlan0); Chromium maps it to nginx."""
STRANGER = "stranger.example"
"""Another site (Chromium maps it to the proxy's other port too: a page there is of another origin)."""
COCKPIT_PAGE = """<!doctype html><meta charset="utf-8"><title>Cockpit stand-in</title>
<style>body { margin: 0 } iframe { display: block; border: 0; width: WIDTHpx; height: HEIGHTpx }</style>
<iframe id="widget"></iframe>
<script>
  const widget = new URLSearchParams(location.search).get("widget");
  if (widget) document.getElementById("widget").src = widget;
  // what Cockpit's HTTP-request action does (src/libs/actions/http-request.ts): fetch with the stored config
  window.runAction = async (config, vehicle) => {
    const url = new URL(config.url.replace("{{ vehicle-address }}", vehicle));
    for (const [k, v] of Object.entries(config.urlParams)) url.searchParams.set(k, v);
    try {
      const r = await fetch(url, { method: config.method, headers: config.headers,
                                   body: config.method === "GET" ? undefined : config.body });
      return [r.status, await r.text()];
    } catch (err) {
      return [0, String(err)];
    }
  };
  window.read = async (url) => {
    try { const r = await fetch(url); return [r.status, await r.text()]; } catch (err) { return [0, String(err)]; }
  };
</script>
""".replace("WIDTH", str(WIDGET_SIZE[0])).replace("HEIGHT", str(WIDGET_SIZE[1]))
ACTION_ORDER = ("stop", "start", "like-newest", "unlike-newest", "topic-main")


def request(url: str, method: str = "GET", *, host: str | None = None, headers: dict | None = None,
            body: bytes | None = None) -> tuple[int, dict[str, str], bytes]:
    """One HTTP request to ``url``, with ``host`` as its Host header when given (a name Chromium maps)."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port or 80, timeout=60)
    try:
        sent = {**({"Host": host} if host else {}), **(headers or {})}
        conn.request(method, parts.path + (f"?{parts.query}" if parts.query else ""), body=body, headers=sent)
        answer = conn.getresponse()
        return answer.status, {k.lower(): v for k, v in answer.getheaders()}, answer.read()
    finally:
        conn.close()


def blueos_name(service: dict) -> str:
    """The helper's ``sanitized_name`` of a /register_service answer."""
    return re.sub(facts.SANITIZE_PATTERN, "", service["name"].lower())


class Extension:
    """The `merlion extension` process; ``restart`` stops it and starts it again on the same port (as BlueOS
    restarts an extension's container)."""

    def __init__(self, root: Path, router_port: int, cfg: Path) -> None:
        self.root = root
        self.argv = [sys.executable, "-m", "companion", "extension", "--data", str(root / "data"), "--host",
                     "0.0.0.0", "--router", f"127.0.0.1:{router_port}", "--config", str(cfg), "--source", SOURCE]
        self.port = 0
        self.proc: subprocess.Popen | None = None
        self.start()

    def start(self) -> None:
        with open(self.root / "extension.log", "ab") as ext_log:
            self.proc = subprocess.Popen([*self.argv, "--port", str(self.port)], cwd=REPO, stdout=subprocess.PIPE,
                                         stderr=ext_log, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        line = self.proc.stdout.readline()
        match = re.search(r"page at http://127\.0\.0\.1:(\d+)/", line)
        assert match, f"no page line: {line!r} (exit {self.proc.poll()})"
        self.port = int(match.group(1))

    def restart(self) -> None:
        self.stop()
        self.start()

    def stop(self) -> None:
        if self.proc is not None:
            stop_process(self.proc, 60)
            self.proc.stdout.close()

    @property
    def data(self) -> Path:
        return self.root / "data"

    def logs(self) -> str:
        """The tails of the companion's and the extension's logs, for a failure's message."""
        tails = []
        for path in (self.data / "companion.log", self.root / "extension.log"):
            text = path.read_text(errors="replace") if path.exists() else "(none)"
            tails.append(f"{path.name}: ...{text[-1500:]}")
        return "\n".join(tails)


@pytest.fixture(scope="module")
def blueos(tmp_path_factory):
    """The extension (its companion on the simulated dive) and nginx as BlueOS sets it up for it."""
    chromium_or_skip()
    root = tmp_path_factory.mktemp("extension")
    cfg = write_config(root / "merlion.yaml", sampler={"k": 4}, queries={"tau_ss": 0.3},
                       surface={"budget_bytes_per_s": 40000, "status_hz": 2, "ftp_writable": True})
    placed = compile_profile({**DEFAULT_PROFILE, "origin": {**DEFAULT_PROFILE["origin"], "after_s": 0}})
    with simulated_vehicle(profile=placed) as (router, _sim, _listener):  # an EKF origin from the start
        ext = Extension(root, router.port, cfg)
        proxy = None
        try:
            # what BlueOS's helper does: read /register_service on the port, write the route for its name
            service = json.loads(request(f"http://127.0.0.1:{ext.port}/register_service")[2])
            proxy = BlueOSProxy(root / "nginx", blueos_name(service), ext.port)
            (proxy.cockpit / "host.html").write_text(COCKPIT_PAGE)
            yield ext, proxy, service
        finally:
            if proxy is not None:
                proxy.close()
            ext.stop()


def browser(proxy: BlueOSProxy, url: str) -> Page:
    """Chromium reaching BlueOS by its names (port 80) and the stranger's site (the proxy's other port)."""
    rules = f"--host-resolver-rules=MAP {VEHICLE} {proxy.vehicle}, MAP {STRANGER} 127.0.0.1"
    return Page(url, flags=(rules, "--disable-features=HttpsUpgrades"))


def vehicle_base(proxy: BlueOSProxy) -> str:
    """BlueOS by its name on port 80, as Chromium reaches it."""
    return proxy.vehicle_base(VEHICLE)


def vehicle_ip(proxy: BlueOSProxy) -> str:
    """The same server for ``request`` (which sends ``host=VEHICLE``)."""
    return f"http://{proxy.vehicle}:{proxy.vehicle_port}"


def route(proxy: BlueOSProxy, service: dict) -> str:
    """The page's address through BlueOS's port 80, by BlueOS's name: App.vue's ``route ?? address``."""
    link = service.get("route") or facts.SIDEBAR_ADDRESS.format(name=blueos_name(service))
    return vehicle_base(proxy) + link


def state_through(proxy: BlueOSProxy, service: dict) -> dict:
    status, _, body = request(f"{proxy.base}{facts.SIDEBAR_ADDRESS.format(name=blueos_name(service))}api/state")
    assert status == 200, body
    return json.loads(body)


def test_blueos_facts_hold():
    """The path BlueOS derives from our name is the one every URL we hand out uses; no route replaces the sidebar
    link; our port is none of BlueOS's; its names are all accepted; nothing we hand out carries a secret."""
    name = re.sub(facts.SANITIZE_PATTERN, "", TITLE.lower())
    assert BASE == f"/extensionv2/{name}" and facts.SIDEBAR_ADDRESS.format(name=name) == f"{BASE}/"
    service = register_service(__version__)
    assert service["name"] == TITLE and "route" not in service and service["works_in_relative_paths"] is True
    assert PORT not in facts.SYSTEM_SERVICE_PORTS | facts.SKIP_PORTS | facts.NGINX_PORTS
    assert not 9000 <= PORT <= 9150  # the block BlueOS adds its own services in
    names = set(vehicle_names())
    assert {f"{n}.local" for ns in facts.BEACON_NAMES.values() for n in ns} <= names
    assert set(facts.BEACON_NAMES["wlan0"] + facts.BEACON_NAMES["uap0"]) <= names
    for action in cockpit_extras(__version__, ["main"])["actions"]:
        config = action["config"]
        assert config["url"].startswith(f"http://{{{{ vehicle-address }}}}{BASE}/api/")
        assert config["headers"] == {}  # no secret, and a simple request: no preflight to answer twice
    assert "Host $host" in facts.LOCATION_TEMPLATE and "Access-Control-Allow-Origin *" in facts.SERVER_HEADERS[0]


def test_what_blueos_and_cockpit_read(blueos):
    ext, proxy, service = blueos
    direct = f"http://127.0.0.1:{ext.port}"
    status, headers, body = request(f"{direct}/")  # what BlueOS's helper checks: 200 with a <title>
    assert status == 200 and re.search(rb"<title>[^<]+</title>", body)
    for key in ("name", "description", "icon", "company", "version", "webpage", "api"):
        assert isinstance(service[key], str), key
    assert service["works_in_relative_paths"] is True and service["extras"]["cockpit"] == "/cockpit_extras.json"
    assert "route" not in service
    assert blueos_name(service) == BASE.rsplit("/", 1)[1]
    assert (proxy.root / "extensions" / f"{blueos_name(service)}.conf").read_text() == proxy.location

    # as Cockpit reads it: through BlueOS, by name, from its own origin
    status, headers, body = request(f"{vehicle_ip(proxy)}{BASE}/cockpit_extras.json", host=VEHICLE,
                                    headers={"Origin": f"http://{VEHICLE}:8000"})
    assert status == 200 and headers["access-control-allow-origin"] == "*"  # BlueOS's proxy opens every answer
    extras = json.loads(body)
    assert extras["targetSystem"] == extras["target_system"] == "Cockpit"
    (widget,) = extras["widgets"]
    assert widget["iframe_url"] == "/widget" and widget["iframeUrl"] == "/widget"
    assert request(f"{vehicle_ip(proxy)}{BASE}{widget['iframe_icon']}", host=VEHICLE)[0] == 200
    assert {a["id"].removeprefix(f"{NAME}-") for a in extras["actions"]} >= set(ACTION_ORDER)
    suggestions = extras["joystickSuggestions"][0]["buttonMappingSuggestions"]
    assert {s["actionId"] for s in suggestions} <= {a["id"] for a in extras["actions"]}

    # BlueOS's names and addresses are this server (Host $host: no port), a rebinding name is not; any address is
    # (one the vehicle got after the extension started: a rebinding page can only send names)
    for host in (VEHICLE, "blueos.local", "blueos-ethernet.local", "blueos-hotspot.local", "companion.local",
                 "127.0.0.1", "203.0.113.7", "[2001:db8::7]"):
        assert request(f"{proxy.base}{BASE}/api/extension", host=host)[0] == 200, host
    assert request(f"{proxy.base}{BASE}/api/extension", host="rebound.example")[0] == 403
    # bad input is a 400 with a reason on every action, not a dropped connection
    origin = {"Origin": f"http://{VEHICLE}"}
    malformed = (b"{not json", b"[1, 2]", b'"text"', b"\xff\xfe{}", b"[" * 100, b'{"a": 1e999999999}x')
    wrong = {"topic": (b'{"topic": []}', b'{"topic": {"a": 1}}', b'{"query": 5}', b'{"query": ""}'),
             "mark": (b'{"index": "x", "kind": "like"}', b'{"index": -1, "kind": "like"}', b'{"index": 1, "kind": 2}'),
             "mark-newest": (b'{"kind": []}',), "companion": (b'{"run": "no"}', b'{}')}
    for action, bodies in wrong.items():
        for body in (*malformed, *bodies):
            status, _, answer = request(f"{proxy.base}{BASE}/api/{action}", "POST", host=VEHICLE, headers=origin,
                                        body=body)
            assert status == 400 and json.loads(answer)["error"], (action, body)

    # BlueOS's frontend takes every path ending in .html, the extension's too: nothing of ours may be one
    assert request(f"{proxy.base}{BASE}/index.html")[2].decode() == FRONTEND_PAGE
    assert not widget["iframe_url"].endswith(".html")
    for page in ("/", "/widget"):
        text = request(f"{proxy.base}{BASE}{page}")[2].decode()
        assert "<title>MERLION" in text, page
        links = re.findall(r'(?:src|href)="([^"]*)"', text)
        assert links and not [link for link in links if urlsplit(link).path.endswith(".html")], (page, links)


def test_sidebar_page_through_blueos(blueos):
    ext, proxy, service = blueos
    wait_until(lambda: sum(1 for f in state_through(proxy, service)["summary"] if f["thumbnail"]) >= 2, 180,
               "two summary frames with thumbnails, through the proxy")
    with browser(proxy, route(proxy, service)) as page:  # what BlueOS's sidebar opens, by BlueOS's name
        assert page.wait_for(f"location.pathname === '{BASE}/' && location.host === '{VEHICLE}'", 30), \
            page.evaluate("location.href")
        decoded = page.wait_for("(n => n >= 2 && n)(Array.from(document.querySelectorAll('#gallery img'))"
                                ".filter((i) => i.complete && i.naturalWidth > 0).length)", 60)
        assert decoded >= 2, f"thumbnails decoded in the full page behind BlueOS's proxy\n{ext.logs()}"
        for _attempt in range(3):  # the frame may leave the summary while the mark is on its way: try again
            index = page.evaluate("Number(document.querySelector('#gallery [data-index]').dataset.index)")
            page.evaluate("document.querySelector('#gallery [data-index] button.like').click()")
            if page.wait_for(f"document.querySelector('#gallery [data-index=\"{index}\"] button.like.on')"
                             " !== null", 30):
                break
        else:
            raise AssertionError(f"the page's mark never took\n{ext.logs()}")
        assert index in state_through(proxy, service)["marks"]["like"]
        # the page's topic switch (the extension's): a preset, followed through the companion
        assert page.wait_for("!document.getElementById('follow').hidden && "
                             "Array.from(document.querySelectorAll('#follow-topic option')).map((o) => o.value)", 30) \
            == ["main"]
        page.evaluate("document.getElementById('follow').requestSubmit()")
        note = page.wait_for("(t => t.startsWith('following') && t)"
                             "(document.getElementById('follow-note').textContent)", 60)
        assert note and note.startswith("following main: "), note


def _widget_tiles(page: Page, frame: str) -> list[dict]:
    return page.evaluate(f"Array.from({frame}.querySelectorAll('.frame')).map((t) => ({{"
                         "index: Number(t.dataset.index), topic: t.querySelector('.topic').textContent, "
                         "score: t.querySelector('.score').textContent, "
                         "below: t.querySelector('.below-mark') !== null, "
                         "bottom: t.querySelector('.tag.bottom').textContent}))")


def run_actions(page: Page, configs: dict[str, dict], vehicle: str, ext: Extension, proxy: BlueOSProxy,
                service: dict, widget: str | None = None) -> None:
    """Every Cockpit action, as Cockpit runs it, from ``page``; each one's effect checked on the extension (and,
    with ``widget``, the expression of the widget's document, the light's reason when the companion is stopped)."""
    for name in ACTION_ORDER:
        if name in ("like-newest", "unlike-newest"):
            wait_until(lambda: (state_through(proxy, service)["companion"]["heartbeat_age_s"] or 99) < 3, 180,
                       f"the companion heard again\n{ext.logs()}")
        status, text = page.evaluate(f"runAction({json.dumps(configs[name])}, {json.dumps(vehicle)})")
        assert status == 200, f"{name}: {status} {text}\n{ext.logs()}"
        answer = json.loads(text)
        if name == "stop":
            assert answer == {"companion_running": False}
            assert "merlion run: seen" in (ext.data / "companion.log").read_text()  # stopped cleanly, store saved
            if widget:
                reason = page.wait_for(f"(r => !r.hidden && r.textContent)({widget}.getElementById('reason'))", 30)
                assert reason and "stopped" in reason
                assert page.evaluate(f"{widget}.getElementById('light').className") == "light down"
        elif name == "start":
            assert answer == {"companion_running": True}
        elif name in ("like-newest", "unlike-newest"):
            kind = name.split("-")[0]
            assert answer["marks"][kind], answer
        else:
            assert answer["topic"] == "main" and answer["status"], answer


def test_widget_and_every_cockpit_action_also_after_a_restart(blueos, tmp_path):
    ext, proxy, service = blueos
    wait_until(lambda: sum(1 for f in state_through(proxy, service)["summary"] if f["thumbnail"]) >= 2, 180,
               "two summary frames with thumbnails, through the proxy")
    status, _, body = request(f"{vehicle_ip(proxy)}{BASE}/cockpit_extras.json", host=VEHICLE)
    extras = json.loads(body)
    configs = {a["id"].removeprefix(f"{NAME}-"): a["config"] for a in extras["actions"]}  # as Cockpit keeps them
    widget_url = f"http://{VEHICLE}{BASE}{extras['widgets'][0]['iframe_url']}"  # Cockpit: base + iframe_url
    vehicle = urlsplit(vehicle_base(proxy)).netloc

    # Cockpit served through BlueOS's port 80: the widget is of its own origin
    with browser(proxy, f"{vehicle_base(proxy)}/cockpit/host.html?widget={widget_url}") as cockpit:
        assert cockpit.wait_for("typeof window.runAction === 'function'", 30), "the Cockpit stand-in loaded"
        frame = "(document.getElementById('widget') || {}).contentDocument"
        decoded = cockpit.wait_for(f"{frame} && {frame}.body && (n => n >= 2 && n)(Array.from("
                                   f"{frame}.querySelectorAll('.frame img'))"
                                   ".filter((i) => i.complete && i.naturalWidth > 0).length)", 60)
        assert decoded >= 2, f"thumbnails decoded in the widget\n{ext.logs()}"
        assert cockpit.wait_for(f"{frame}.getElementById('light').className === 'light ok'", 60)
        assert cockpit.evaluate(f"{frame}.getElementById('reason').hidden") is True
        size = cockpit.evaluate(f"[{frame}.documentElement.clientWidth, {frame}.documentElement.clientHeight]")
        assert tuple(size) == WIDGET_SIZE
        assert cockpit.evaluate(f"{frame}.documentElement.scrollHeight <= {frame}.documentElement.clientHeight")
        options = cockpit.evaluate(f"Array.from({frame}.querySelectorAll('#topic option')).map((o) => o.value)")
        assert "main" in options and cockpit.evaluate(f"{frame}.getElementById('topic').hidden") is False
        # the pilot's own words, then back to a preset through the switch: the answer shown under the header
        cockpit.evaluate(f"{frame}.getElementById('query').value = 'a sandy  seabed'; "
                         f"{frame}.getElementById('ask').requestSubmit()")
        note = cockpit.wait_for(f"(n => !n.hidden && n.textContent.startsWith('following') && n.textContent)"
                                f"({frame}.getElementById('note'))", 60)
        assert note == "following asked: a sandy seabed", note
        cockpit.evaluate(f"(s => {{ s.value = 'main'; s.dispatchEvent(new Event('change')); }})"
                         f"({frame}.getElementById('topic'))")
        assert cockpit.wait_for(f"{frame}.getElementById('note').textContent.startsWith('following main')", 60)
        wait_until(lambda: [t["name"] for t in state_through(proxy, service)["topics"]] == ["main"], 60,
                   "the preset followed again")
        # the screenshot for the docs once a frame of the followed topic is on the widget, its thumbnail decoded
        assert cockpit.wait_for(f"Array.from({frame}.querySelectorAll('.frame')).some((t) => "
                                f"t.querySelector('.topic').textContent === 'main' && "
                                f"t.querySelector('img').naturalWidth > 0)", 120), ext.logs()
        shot = Path(os.environ.get("MERLION_WIDGET_SCREENSHOT") or tmp_path / "widget.png")
        clip = {"x": 0, "y": 0, "width": WIDGET_SIZE[0], "height": WIDGET_SIZE[1], "scale": 1}
        shot.write_bytes(base64.b64decode(cockpit.call("Page.captureScreenshot", format="png", clip=clip)["data"]))
        assert struct.unpack(">II", shot.read_bytes()[16:24]) == WIDGET_SIZE

        held = {f["image_index"]: f for f in state_through(proxy, service)["summary"]}
        tiles = _widget_tiles(cockpit, frame)
        assert tiles
        for tile in tiles:  # every tile: topic, score, the below-threshold mark, depth and capture time
            f = held.get(tile["index"])
            if f is None:
                continue  # left the summary meanwhile
            assert tile["topic"] == (f["topic"] or "no topic") and tile["score"] == f"{f['score']:.2f}"
            assert tile["below"] == f["below_threshold"]
            assert re.search(r"#\d+ \d+\.\d m \d\d:\d\d:\d\d$", tile["bottom"]), tile
        run_actions(cockpit, configs, vehicle, ext, proxy, service, widget=frame)

    ext.restart()  # a new process on the same port; Cockpit keeps the actions it applied
    wait_until(lambda: request(f"{proxy.base}{BASE}/api/extension")[0] == 200, 60, "the extension back")
    # Cockpit on another port of the vehicle (its own extension's): another origin than the page's, the same host
    with browser(proxy, f"{proxy.base}/cockpit/host.html?widget={proxy.base}{BASE}/widget") as cockpit:
        assert cockpit.wait_for("typeof window.runAction === 'function'", 30), "the Cockpit stand-in loaded"
        frame = "(document.getElementById('widget') || {}).contentDocument"
        assert cockpit.wait_for(f"{frame} && {frame}.getElementById('light') && "
                                f"{frame}.getElementById('light').className === 'light ok'", 180), ext.logs()
        run_actions(cockpit, configs, vehicle, ext, proxy, service)


def _framed(page: Page) -> dict[str, str]:
    """Other origins' frames (each its own DevTools target, site isolation): the URL each was sent to -> the title
    and address of the document it shows (one refused by frame-ancestors shows Chromium's error page)."""
    titles = {}
    for target in page.call("Target.getTargets")["targetInfos"]:
        if target["type"] != "iframe":
            continue
        session = page.call("Target.attachToTarget", targetId=target["targetId"], flatten=True)["sessionId"]
        done = page.call("Runtime.evaluate", session, expression="document.title + ' @ ' + location.href",
                         returnByValue=True)
        titles[target["url"]] = done["result"].get("value", "")
        page.call("Target.detachFromTarget", sessionId=session)
    return titles


def _include(tag: str, url: str, policy: str = "no-referrer") -> str:
    """JavaScript that includes ``url`` as a ``<script>`` or ``<img>`` under the referrer ``policy`` (as any page
    can), answering "loaded" or "error"."""
    return (f"new Promise((done) => {{ const e = document.createElement({json.dumps(tag)}); "
            f"e.referrerPolicy = {json.dumps(policy)}; e.onload = () => done('loaded'); "
            f"e.onerror = () => done('error'); e.src = {json.dumps(url)}; document.body.appendChild(e); }})")


def test_a_stranger_reads_only_what_blueos_opens_and_changes_nothing(blueos):
    ext, proxy, service = blueos
    stranger = f"http://{STRANGER}:{proxy.port}"
    vehicle = urlsplit(vehicle_base(proxy)).netloc
    target = f"{vehicle_base(proxy)}{BASE}"
    extras = json.loads(request(f"{vehicle_ip(proxy)}{BASE}/cockpit_extras.json", host=VEHICLE)[2])
    stop = next(a["config"] for a in extras["actions"] if a["id"] == f"{NAME}-stop")
    wait_until(lambda: json.loads(request(f"{proxy.base}{BASE}/api/extension")[2])["companion_running"], 60,
               "the companion running")
    likes = state_through(proxy, service)["marks"]["like"]
    wait_until(lambda: state_through(proxy, service)["summary"], 180, "a summary frame")
    frame = state_through(proxy, service)["summary"][0]["image_index"]

    with browser(proxy, f"{stranger}/cockpit/host.html?widget={target}/widget") as page:
        assert page.wait_for("typeof window.read === 'function'", 30), "the stranger's page loaded"
        # what BlueOS's proxy opens to every site (Access-Control-Allow-Origin *): read, but no secret in it
        for path in ("/cockpit_extras.json", "/register_service", "/", "/widget"):
            status, text = page.evaluate(f"read({json.dumps(target + path)})")
            assert status == 200 and "token" not in text.lower(), path
        # the state is not: refused by the extension, so the proxy adds no CORS header and the read fails
        for path in ("/api/state", "/api/extension", "/state.js"):
            status, _text = page.evaluate(f"read({json.dumps(target + path)})")
            assert status == 0, path
        # nor by including what names no page: over plain HTTP to the vehicle's name Chromium sends no Origin (a
        # classic script, an image), no Sec-Fetch-Site, and no Referer under the stranger's referrer policy
        assert page.evaluate(_include("script", f"{target}/state.js")) == "error"
        assert page.evaluate("typeof window.MERLION_STATE") == "undefined"
        assert page.evaluate(_include("img", f"{target}/full/{frame}.jpg")) == "error"  # it spends the link
        # Cockpit's own action, run from a stranger's page, and a plain cross-site post: refused
        assert page.evaluate(f"runAction({json.dumps(stop)}, {json.dumps(vehicle)})")[0] == 0
        # what a form post does: a no-cors POST (no preflight), whose answer the page never sees
        page.evaluate(f"fetch({json.dumps(target + '/api/mark-newest')}, {{method: 'POST', mode: 'no-cors', "
                      "body: JSON.stringify({kind: 'like'})}).then(() => 1, () => 0)")
        # the widget in a stranger's frame: refused by frame-ancestors (no invisible frame to click through)
        assert poll_until(lambda: f"{target}/widget" in _framed(page), 30, interval=0.5), _framed(page)
        assert _framed(page)[f"{target}/widget"].endswith("@ chrome-error://chromewebdata/"), _framed(page)
    wait_until(lambda: "refused POST /api/mark-newest" in (ext.root / "extension.log").read_text(errors="replace"),
               30, "the form post refused")
    refusals = (ext.root / "extension.log").read_text(errors="replace")
    assert "refused GET /state.js" in refusals and f"refused GET /full/{frame}.jpg" in refusals, refusals[-2000:]
    assert json.loads(request(f"{proxy.base}{BASE}/api/extension")[2])["companion_running"] is True
    assert state_through(proxy, service)["marks"]["like"] == likes

    # the same widget framed by a vehicle page (Cockpit on another port of the vehicle) loads
    with browser(proxy, f"{proxy.base}/cockpit/host.html?widget={target}/widget") as page:
        assert poll_until(lambda: _framed(page).get(f"{target}/widget") ==
                          f"MERLION summary (widget) @ {target}/widget", 30, interval=0.5), _framed(page)
        # and a vehicle page including the state as a script names itself (its Referer): it gets it
        assert page.evaluate(_include("script", f"{target}/state.js", policy="")) == "loaded"
        assert page.evaluate("typeof window.MERLION_STATE.summary") == "object"


def test_bad_arguments_are_one_line_and_exit_2(tmp_path):
    done = run_merlion("extension", "--data", str(tmp_path / "d"), "--router", "nowhere", "--duration", "1")
    assert done.returncode == 2 and done.stderr.strip() == \
        "merlion: error: --router 'nowhere': expected HOST:PORT (e.g. 127.0.0.1:14660)"
    bad = tmp_path / "bad.yaml"
    bad.write_text("sampler:\n  k: 0\n")
    done = run_merlion("extension", "--data", str(tmp_path / "d"), "--config", str(bad), "--duration", "1")
    assert done.returncode == 2 and done.stderr.strip().startswith(f"merlion: error: {bad}")
