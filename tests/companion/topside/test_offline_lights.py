"""A saved page (DIR/index.html opened from disk) never shows green "live" lights: it is a record, not a link."""

from __future__ import annotations

from companion.topside.offline_page import write_offline_page
from tests.companion.topside.browser import Page, chromium_or_skip

GREEN = "rgb(51, 204, 51)"  # .ok .dot in index.html


def saved_state() -> dict:
    """The state of a healthy link at the moment it was saved: messages 0.4 s ago, a heartbeat 0.8 s ago."""
    link = {"messages": 812, "last_message_age_s": 0.4, "lost_packets": 0, "pushed_ok": 3, "pushed_lost": 0,
            "ftp_ok": 0, "ftp_failed": 0, "verified": 3, "mismatched": 0}
    companion = {"id": [1, 100], "heartbeat_age_s": 0.8, "values": {}, "statustext": [], "warnings": [],
                 "depth_track": [[1.7e9, 2.0], [1.7e9 + 10, 7.0]]}
    return {"time": 1.7e9 + 10, "link": link, "companion": companion, "dive": "5e1f0c2a", "topics": [],
            "summary": [], "marks": {"like": [], "unlike": []}}


def test_the_saved_page_lights_are_grey_and_say_when_saved(tmp_path):
    chromium_or_skip()
    page_file = write_offline_page(tmp_path, saved_state())
    with Page(page_file.as_uri()) as page:
        assert page.wait_for("document.getElementById('dive') !== null && document.getElementById('dive').textContent === 'dive 5e1f0c2a'")
        for light in ("link", "companion"):
            assert page.evaluate(f"document.getElementById('{light}').className") == "saved"
            colour = page.evaluate(f"getComputedStyle(document.querySelector('#{light} .dot')).backgroundColor")
            assert colour != GREEN, colour
            assert page.evaluate(f"document.querySelector('#{light} .text').textContent").endswith("(when saved)")
        assert "812 msgs" in page.evaluate("document.querySelector('#link .text').textContent")
