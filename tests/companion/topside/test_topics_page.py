"""Several topics on the surface page: a section per topic, headed by its positive query, each card in its topic's.

The live test runs a real ``merlion surface --web 0`` fed by the real companion-side Downlink following two topics
over UDP, and reads the page in headless Chromium; the offline tests draw a saved page (DIR/index.html + state.js,
written by the tool's own writer) to check that one topic looks as it always did.
"""

from __future__ import annotations

import dataclasses
import json

from companion.config import SurfaceConfig
from companion.topside.offline_page import write_offline_page
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import summary_frame
from tests.companion.topside.browser import Page, chromium_or_skip
from tests.companion.topside.live_page import companion_downlink, page_state, surface_with_page
from tests.conftest import free_udp_port
from tests.waiting import wait_until
from vehicle.protocol.queries import QueryTopic

FISH = QueryTopic("fish", "underwater image with fish", ("underwater image without fish",))
CORAL = QueryTopic("coral", "underwater image of a coral reef", ("underwater image of sand",))
SECTION = "document.querySelector('#gallery section.topic[data-topic=\"{}\"]')"


def _cards(page: Page, topic: str) -> list[str]:
    return page.evaluate(f"[...{SECTION.format(topic)}.querySelectorAll('figure.frame')].map(f => f.dataset.index)")


def _frame(index: int, topic: str, depth: float):
    return dataclasses.replace(summary_frame(index, depth=depth), topic=topic)


def test_two_topics_show_as_two_sections_and_a_new_capture_lands_in_its_own(tmp_path):
    chromium_or_skip()
    port = free_udp_port()
    out = tmp_path / "gallery"
    with surface_with_page(out, port) as shown, \
            companion_downlink(port, SurfaceConfig(budget_bytes_per_s=20000), queries=[FISH, CORAL]) as surface:
        proc, page_url, web = shown.proc, shown.url, shown.web
        assert wait_until(lambda: page_state(web)["companion"]["id"] == [1, 100], 15)
        surface.publish(SummaryEvent("added", _frame(5, "fish", 10.0), summary=[5]))
        surface.publish(SummaryEvent("added", _frame(6, "coral", 11.0), summary=[5, 6]))
        surface.publish(SummaryEvent("added", _frame(7, "fish", 12.0), summary=[5, 6, 7]))

        def ready() -> bool:
            s = page_state(web)
            return ([t["name"] for t in s["topics"]] == ["fish", "coral"]
                    and {f["image_index"]: f["topic"] for f in s["summary"]} == {5: "fish", 6: "coral", 7: "fish"}
                    and all(f["thumbnail"] for f in s["summary"]))

        assert wait_until(ready, 30), page_state(web)
        with Page(page_url) as page:
            assert page.wait_for("document.querySelectorAll('#gallery section.topic').length == 2"
                                 " && document.querySelectorAll('#gallery figure.frame img').length == 3")
            headings = page.evaluate("[...document.querySelectorAll('#gallery section.topic h2')]"
                                     ".map(h => h.innerText)")
            assert FISH.positive in headings[0] and "topic fish" in headings[0], headings  # the topics' order
            assert CORAL.positive in headings[1] and "topic coral" in headings[1], headings
            assert _cards(page, "fish") == ["7", "5"] and _cards(page, "coral") == ["6"]  # newest first in each
            assert "topic coral" in page.evaluate(
                "document.querySelector('#gallery figure.frame[data-index=\"6\"]').innerText")
            # a new capture in either topic appears in its own section, with no reload
            page.evaluate("window.notReloaded = true")
            surface.publish(SummaryEvent("added", _frame(8, "coral", 13.0), summary=[5, 6, 7, 8]))
            assert page.wait_for(f"{SECTION.format('coral')}.querySelector('figure.frame[data-index=\"8\"] img')"
                                 " !== null", 30), page_state(web)
            assert _cards(page, "coral") == ["8", "6"] and _cards(page, "fish") == ["7", "5"]
            surface.publish(SummaryEvent("added", _frame(9, "fish", 14.0), summary=[5, 6, 7, 8, 9]))
            assert page.wait_for(f"{SECTION.format('fish')}.querySelector('figure.frame[data-index=\"9\"] img')"
                                 " !== null", 30), page_state(web)
            assert page.evaluate("window.notReloaded === true")
            # the marks buttons are still on every card (they teach the marked frame's topic on board)
            assert page.evaluate("document.querySelectorAll('#gallery figure.frame button.mark.like').length") == 5
        proc.terminate()
        stdout, _ = proc.communicate(timeout=30)
    assert "5 frames in the summary (fish 3, coral 2), 5 with thumbnails" in stdout, stdout
    doc = json.loads((out / "gallery.json").read_text())
    assert [t["name"] for t in doc["topics"]] == ["fish", "coral"]
    assert {c["image_index"]: c["topic"] for c in doc["captures"]} == {5: "fish", 6: "coral", 7: "fish", 8: "coral",
                                                                        9: "fish"}


def _saved_state(topics: list[dict], frames: list[dict]) -> dict:
    link = {"messages": 0, "last_message_age_s": None, "lost_packets": 0, "pushed_ok": 0, "pushed_lost": 0,
            "ftp_ok": 0, "ftp_failed": 0, "verified": 0, "mismatched": 0}
    companion = {"id": None, "heartbeat_age_s": None, "values": {}, "statustext": [], "warnings": [],
                 "depth_track": []}
    return {"time": 1.7e9, "link": link, "companion": companion, "dive": "5e1f0c2a", "topics": topics,
            "summary": frames, "marks": {"like": [], "unlike": []}}


def _saved_frame(index: int, topic: str | None) -> dict:
    return {"image_index": index, "dive": "5e1f0c2a", "time_utc": 1.7e9 + index, "depth_m": 5.0, "topic": topic,
            "score": 0.7, "thumbnail": None}


def test_one_topic_shows_as_it_always_did(tmp_path):
    chromium_or_skip()
    main = {"name": "main", "positive": "underwater image with fish", "negatives": ["no fish"]}
    page_file = write_offline_page(tmp_path, _saved_state([main], [_saved_frame(2, "main"), _saved_frame(1, "main")]))
    with Page(page_file.as_uri()) as page:
        assert page.wait_for("document.querySelectorAll('#gallery figure.frame').length == 2")
        assert page.evaluate("document.querySelectorAll('#gallery section.topic').length") == 0
        assert "topic" not in page.evaluate("document.getElementById('gallery').innerText")  # no clutter


def test_a_frame_whose_topic_is_not_known_yet_waits_in_its_own_section(tmp_path):
    chromium_or_skip()
    topics = [{"name": "fish", "positive": "fish", "negatives": ["no fish"]},
              {"name": "coral", "positive": "coral", "negatives": ["sand"]}]
    frames = [_saved_frame(3, None), _saved_frame(2, "fish")]  # 3 pushed before the index said its topic
    page_file = write_offline_page(tmp_path, _saved_state(topics, frames))
    with Page(page_file.as_uri()) as page:
        assert page.wait_for("document.querySelectorAll('#gallery section.topic').length == 3")
        assert _cards(page, "fish") == ["2"] and _cards(page, "coral") == [] and _cards(page, "") == ["3"]
        assert "No summary frames yet" in page.evaluate(f"{SECTION.format('coral')}.innerText")
        assert "topic not known yet" in page.evaluate(f"{SECTION.format('')}.innerText")


def test_topics_no_index_has_listed_yet_show_under_their_names_in_a_steady_order(tmp_path):
    chromium_or_skip()
    frames = [_saved_frame(4, "fish"), _saved_frame(3, "coral"), _saved_frame(2, "fish")]  # from status lines only
    page_file = write_offline_page(tmp_path, _saved_state([], frames))
    with Page(page_file.as_uri()) as page:
        assert page.wait_for("document.querySelectorAll('#gallery section.topic').length == 2")
        assert page.evaluate("[...document.querySelectorAll('#gallery section.topic')].map(s => s.dataset.topic)"
                             ) == ["coral", "fish"]
        assert _cards(page, "fish") == ["4", "2"]
        assert page.evaluate(f"{SECTION.format('coral')}.querySelector('h2').innerText").startswith("coral")
