"""The page-state role of the surface tool: the JSON view of the link, the companion and the summary that the live
page polls, and the offline copy of the page written beside the gallery. Read from the web server's threads."""

from __future__ import annotations

import logging
import math
import time

from companion.topside.capture import Capture
from companion.topside.offline_page import write_offline_page
from companion.topside.surface_state import SurfaceContext

log = logging.getLogger("merlion.surface")


class PageState:
    """What the page shows, built under the context's lock."""

    def __init__(self, ctx: SurfaceContext) -> None:
        self.ctx = ctx

    def write_offline_page(self) -> None:
        """DIR/index.html (+ app.js, state.js): the page as of now, opened from disk without a server."""
        try:
            write_offline_page(self.ctx.gallery.root, self.snapshot())
        except OSError as err:
            log.warning("%s: cannot write the offline page (%s)", self.ctx.gallery.root, err.strerror or err)

    def snapshot(self) -> dict:
        """A JSON-ready view of the link, the companion and the summary (newest first)."""
        ctx = self.ctx
        now = time.time()
        with ctx.lock:
            s = ctx.status
            link = {
                "connect": ctx.options.connect,
                "messages": s.messages,
                "last_message_age_s": None if s.last_message is None else round(now - s.last_message, 1),
                "lost_packets": s.lost_packets, "other_address_messages": s.other_address_messages,
                "autopilot": list(s.autopilot) if s.autopilot else None,
                "autopilot_heartbeat_age_s": _age(now, s.autopilot_heartbeat),
                "foreign_autopilot_heartbeats": s.foreign_autopilot_heartbeats,
                "pushed_ok": s.pushed_ok, "pushed_lost": s.pushed_lost,
                "ftp_ok": s.ftp_ok, "ftp_failed": s.ftp_failed, "index_pulls": s.index_pulls,
                "verified": s.verified, "mismatched": s.mismatched,
                "unsigned_ignored": s.unsigned_ignored, "unpaired_dropped": s.unpaired_dropped,
                "requests_refused": s.requests_refused,
                "waiting_overflow": s.waiting_overflow, "fetches_dropped": s.fetches_dropped,
                "bound_dropped": s.bound_dropped,
                "inbox_dropped": s.inbox_dropped, "values_dropped": s.values_dropped,
                "unsigned_sources": {f"{a}/{b}": n for (a, b), n in sorted(s.unsigned_sources.items())},
            }
            companion = {
                "id": list(s.companion) if s.companion else None,
                "heartbeat_age_s": _age(now, s.companion_heartbeat),
                "values": {k: (v if math.isfinite(v) else None) for k, v in s.values.items()},  # strict JSON
                "values_age_s": _age(now, s.values_at),
                "statustext": list(s.statustext)[::-1],
                "warnings": list(s.warnings)[::-1],
                "depth_track": list(s.depth_track),
            }
            marks = {k: list(v) for k, v in ctx.marks.items()}
        summary = [_capture_view(c) for c in ctx.gallery.summary()]
        topics = [t.to_dict() for t in ctx.gallery.topics()]
        return {"time": now, "link": link, "companion": companion, "dive": ctx.gallery.dive, "summary": summary,
                "history_dropped": ctx.gallery.history_dropped, "log_rows_dropped": ctx.gallery.log_rows_dropped,
                "archived_dropped": ctx.gallery.archived_dropped,
                "topics": topics,
                "thumbnails_waiting": ctx.gallery.missing_thumbnails(), "marks": marks}


def _age(now: float, then: float | None) -> float | None:
    return None if then is None else round(now - then, 1)


def _capture_view(c: Capture) -> dict:
    return {
        "image_index": c.image_index, "dive": c.dive, "time_utc": c.time_utc, "depth_m": c.depth_m,
        "heading_deg": c.heading_deg, "score": c.score, "raw_score": c.raw_score,
        "topic": c.topic,
        "below_threshold": bool(c.below_threshold), "lat": c.lat, "lon": c.lon,
        "alt_m": c.alt_m, "thumbnail": c.thumbnail, "via": c.thumbnail_via, "bytes": c.thumbnail_bytes,
    }
