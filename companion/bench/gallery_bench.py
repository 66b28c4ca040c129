"""What keeping gallery.json costs the surface tool's receive loop when every cap of the gallery is full.

A folder at the caps (``MAX_SUMMARY`` frames in the summary, ``MAX_HISTORY`` trimmed, ``MAX_ARCHIVED`` captures of
``MAX_DIVES`` earlier dives, every tag filled in) is written as a gallery.json and opened with the real ``Gallery``.
Then: one change written through (the rewrite a lone Gallery does), and the receive loop's own pattern for a few
seconds (a change, then ``flush_due``, with the tool's 0.25 s throttle, ``rate`` changes a second, as a busy
companion's captures, tags and trims come): how many it handled, how much of its time went into the gallery's calls
and into those that rewrote gallery.json, and its longest stall.
"""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

from companion.topside import gallery as gallery_module
from companion.topside.gallery import Gallery


def _capture(index: int, dive: str, *, in_summary: bool, topic: str) -> dict:
    """Every field a real capture ends up with (the longest rows the file holds)."""
    now = 1_790_000_000.0 + index
    return {
        "image_index": index, "dive": dive, "time_utc": now, "depth_m": 12.345 + index % 50,
        "heading_deg": 123.4, "q": [0.9238795325112867, 0.0, 0.0, 0.3826834323650898], "lat": -33.8568001,
        "lon": 151.2152967, "alt_m": -12.3, "score": 0.3141592653589793, "raw_score": 0.2718281828459045,
        "topic": topic, "below_threshold": False, "file_url": f"mftp://summary/{dive}/{index}.jpg",
        "thumbnail": f"{'summary' if in_summary else 'removed'}/{index}.jpg", "thumbnail_via": "push",
        "thumbnail_bytes": 2481, "thumbnail_crc32": 3735928559, "in_summary": in_summary, "announced_at": now + 0.5,
        "removed_at": None if in_summary else now + 60.0,
    }


def fill_gallery(root: Path) -> dict:
    """Write a gallery.json holding as much as the gallery ever keeps; returns its counts."""
    dive = "cafe0001"
    summary = gallery_module.MAX_SUMMARY
    history = gallery_module.MAX_HISTORY
    archived_n = gallery_module.MAX_ARCHIVED
    dives_n = gallery_module.MAX_DIVES
    topics = [f"topic{t}" for t in range(8)]
    captures = [_capture(i, dive, in_summary=i >= history, topic=topics[i % 8]) for i in range(history + summary)]
    old = [f"{d:08x}" for d in range(dives_n - 1)]
    archived = []
    for i in range(archived_n):
        d = old[i * len(old) // archived_n]
        cap = _capture(i, d, in_summary=False, topic=topics[i % 8])
        cap["thumbnail"] = f"dives/{d}/removed/{i}.jpg"
        archived.append(cap)
    doc = {
        "updated": time.time(), "dive": dive, "dives": [*old, dive],
        "summary": [c["image_index"] for c in captures if c["in_summary"]], "captures": captures,
        "archived": archived,
        "topics": [{"name": t, "positive": f"a photo of {t}", "negatives": ["sand", "water"]} for t in topics],
        "history_dropped": 0, "archived_dropped": 0,
    }
    root.mkdir(parents=True, exist_ok=True)
    (root / "gallery.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return {"captures": len(captures), "summary": summary, "archived": archived_n, "dives": dives_n}


def measure_gallery(root: Path, *, seconds: float = 5.0, every_s: float = 0.25, rate: float = 2000.0,
                    write_through: int = 5) -> dict:
    """Fill a gallery at ``root`` to every cap, then time its gallery.json rewrites (see the module's doc)."""
    counts = fill_gallery(root)
    t0 = time.perf_counter()
    gallery = Gallery(root)
    open_s = time.perf_counter() - t0
    first = gallery_module.MAX_HISTORY  # the summary's frames: a score learnt later, as index.json brings
    singles = []
    for n in range(write_through):
        t0 = time.perf_counter()
        gallery.update_tags(first + n, score=0.5 + n / 100)
        singles.append(time.perf_counter() - t0)

    gallery.defer_writes(every_s)
    writes_before = gallery.json_writes
    changes, writing_s, busy_s, worst = 0, 0.0, 0.0, 0.0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        wait = start + changes / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        index = first + changes % gallery_module.MAX_SUMMARY
        t0 = time.perf_counter()
        writes = gallery.json_writes
        gallery.update_tags(index, score=0.25 + (changes % 1000) / 10_000)
        gallery.flush_due()
        took = time.perf_counter() - t0
        busy_s += took
        worst = max(worst, took)
        if gallery.json_writes != writes:
            writing_s += took
        changes += 1
    wall = time.perf_counter() - start
    t0 = time.perf_counter()
    gallery.flush()
    close = getattr(gallery, "close", None)
    if close is not None:
        close()
    flush_s = time.perf_counter() - t0
    on_disk = json.loads((root / "gallery.json").read_text(encoding="utf-8"))
    last = first + (changes - 1) % gallery_module.MAX_SUMMARY
    last_ok = next(c for c in on_disk["captures"] if c["image_index"] == last)["score"] == \
        0.25 + ((changes - 1) % 1000) / 10_000
    return {
        **counts, "gallery_json_bytes": (root / "gallery.json").stat().st_size, "open_s": round(open_s, 3),
        "rewrite_s": round(statistics.median(singles), 4),
        "loop_seconds": round(wall, 2), "rate": rate,
        "loop_changes": changes, "changes_per_s": round(changes / wall), "loop_share_busy": round(busy_s / wall, 4),
        "rewrites": gallery.json_writes - writes_before, "loop_share_writing": round(writing_s / wall, 4),
        "worst_stall_s": round(worst, 4), "final_flush_s": round(flush_s, 4), "last_state_on_disk": last_ok,
    }
