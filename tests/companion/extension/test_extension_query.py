"""The widget's and the page's query switch on a companion with the packaged encoder (ImageNet classes): words the
encoder can read are followed; words it cannot ("kelp") are refused with the companion's reason as a 400, and the
companion keeps running with the topics it had."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from tests.companion.live_harness import simulated_vehicle, wait_until, write_config
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.conftest import REPO, stop_process

from .test_extension import request

ORIGIN = {"Origin": "http://blueos-hotspot.local"}
"""A page the vehicle serves (BlueOS's name on its hotspot)."""


@pytest.fixture(scope="module")
def packaged(tmp_path_factory):
    root = tmp_path_factory.mktemp("query")
    cfg = write_config(root / "merlion.yaml", encoder={"name": "imagenet"}, sampler={"k": 4},
                       queries={"positive": "underwater image with fish",
                                "negatives": ["underwater image of a sandbar"],
                                "tau_ss": 0.3},
                       surface={"budget_bytes_per_s": 40000, "status_hz": 2, "ftp_writable": True})
    with simulated_vehicle() as (router, _sim, _listener), open(root / "extension.log", "wb") as ext_log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion", "extension", "--data", str(root / "data"), "--port", "0",
             "--host", "127.0.0.1", "--router", f"127.0.0.1:{router.port}", "--config", str(cfg),
             "--source", "synthetic://dive?seconds=600&width=320&height=192"],
            cwd=REPO, stdout=subprocess.PIPE, stderr=ext_log, text=True)
        try:
            line = proc.stdout.readline()
            match = re.search(r"page at http://127\.0\.0\.1:(\d+)/", line)
            assert match, f"no page line: {line!r} (exit {proc.poll()})"
            yield f"http://127.0.0.1:{match.group(1)}", root / "data"
        finally:
            stop_process(proc, 60)


def _post(base: str, body: dict) -> tuple[int, dict]:
    status, _, answer = request(f"{base}/api/topic", "POST", headers=ORIGIN, body=json.dumps(body).encode())
    return status, json.loads(answer)


def _state(base: str) -> dict:
    return json.loads(request(f"{base}/api/state")[2])


@pytest.mark.slow
def test_a_query_the_encoder_cannot_read_is_refused_and_the_companion_keeps_its_topics(packaged):
    chromium_or_skip()
    base, data = packaged
    def log() -> str:
        return (data / "companion.log").read_text(errors="replace")

    wait_until(lambda: "companion running" in log() or "merlion: error" in log(), 240,
               "the companion with the packaged encoder")
    assert "companion running" in log(), log()[-2000:]
    wait_until(lambda: (_state(base)["companion"]["heartbeat_age_s"] or 99) < 3, 120, "the companion heard")
    before = [t["name"] for t in _state(base)["topics"]]

    status, answer = _post(base, {"query": "kelp"})
    assert status == 400, answer
    assert "kelp" in answer["error"] and "refused" in answer["error"].lower(), answer
    assert "companion stopped" not in log(), log()[-2000:]
    assert json.loads(request(f"{base}/api/extension")[2])["companion_running"] is True
    wait_until(lambda: (_state(base)["companion"]["heartbeat_age_s"] or 99) < 3, 60, "the companion still heard")
    assert [t["name"] for t in _state(base)["topics"]] == before

    for bad in ({"query": ""}, {"query": ["kelp"]}, {"query": "x" * 201}):
        status, answer = _post(base, bad)
        assert status == 400 and answer["error"].startswith("query"), (bad, answer)

    # the same on the widget: typed, refused, the companion's reason shown to the pilot
    with Page(f"{base}/widget") as widget:
        assert widget.wait_for("document.getElementById('ask') && !document.getElementById('ask').hidden", 30)
        widget.evaluate("document.getElementById('query').value = 'kelp'; "
                        "document.getElementById('ask').requestSubmit()")
        note = widget.wait_for("(n => !n.hidden && n.textContent.includes('refused') && n.textContent)"
                               "(document.getElementById('note'))", 60)
        assert note and "kelp" in note, note
    assert json.loads(request(f"{base}/api/extension")[2])["companion_running"] is True

    status, answer = _post(base, {"query": "a  coral reef"})  # words it can read: followed
    assert status == 200 and answer["topic"] == "asked" and answer["query"] == "a coral reef", answer
    wait_until(lambda: [t["name"] for t in _state(base)["topics"]] == ["asked"], 60, "the new topic on the page")
