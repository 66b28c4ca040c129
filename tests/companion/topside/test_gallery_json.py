"""gallery.json joined from kept pieces: the same bytes ``json.dumps(doc, indent=1)`` wrote, and never stale."""

from __future__ import annotations

import json
import math
import random

from companion.topside.capture import Capture, Topic
from companion.topside.gallery import Gallery
from companion.topside.gallery_json import GalleryText, capture_text, list_text


def test_a_capture_and_a_document_are_the_bytes_json_dumps_writes():
    caps = [Capture(image_index=1),
            Capture(image_index=2, q=[1.0, 0.0, 0.5, -0.25], dive="ab", topic='fïsh "x"\n', score=math.nan,
                    depth_m=math.inf, in_summary=False, thumbnail_crc32=3735928559, below_threshold=True)]
    for cap in caps:
        assert capture_text(cap) == json.dumps(cap.to_dict(), indent=1).replace("\n", "\n  ")
    topics = ({"name": "fish", "positive": "a fish", "negatives": ["sand"]},)
    state = GalleryText(updated=1.5, dive="ab", dives=("aa", "ab"), summary=(1,), captures=tuple(map(capture_text, caps)),
                        archived=list_text([capture_text(caps[0])]), topics=topics, history_dropped=3,
                        archived_dropped=0)
    doc = {"updated": 1.5, "dive": "ab", "dives": ["aa", "ab"], "summary": [1], "captures": [c.to_dict() for c in caps],
           "archived": [caps[0].to_dict()], "topics": list(topics), "history_dropped": 3, "archived_dropped": 0}
    assert state.render() == json.dumps(doc, indent=1)
    empty = GalleryText(updated=0.0, dive=None, dives=(), summary=(), captures=(), archived=list_text([]), topics=(),
                        history_dropped=0, archived_dropped=0)
    assert empty.render() == json.dumps({"updated": 0.0, "dive": None, "dives": [], "summary": [], "captures": [],
                                         "archived": [], "topics": [], "history_dropped": 0, "archived_dropped": 0},
                                        indent=1)


def test_after_every_kind_of_change_the_file_is_the_gallerys_state(tmp_path):
    """Each capture's text is kept until it changes: every change the gallery makes must forget it, or the file
    would show an old state. 400 random changes written through, the file checked against the state each time."""
    rng = random.Random(7)
    g = Gallery(tmp_path, max_summary=20, max_history=15, max_archived=30, max_dives=4)
    dive = 0
    g.use_dive(f"d{dive}")
    for step in range(400):
        i = rng.randrange(40)
        kind = rng.randrange(7)
        if kind == 0:
            g.announce(Capture(image_index=i, depth_m=rng.random(), q=[1.0, 0.0, 0.0, rng.random()]))
        elif kind == 1:
            g.update_tags(i, score=rng.random(), topic=rng.choice(["fish", "coral"]))
        elif kind == 2:
            g.add_thumbnail(i, bytes([step % 256]) * 10)
        elif kind == 3:
            g.remove(i)
        elif kind == 4:
            g.mirror(rng.sample(range(40), 5))
        elif kind == 5 and rng.random() < 0.2:
            dive += 1
            g.use_dive(f"d{dive}")
        elif kind == 6:
            g.set_topics([Topic(rng.choice(["fish", "coral"]), "a thing")])
        g.flush()  # a frame forgotten past max_history waits for the next write (as before)
        text = (tmp_path / "gallery.json").read_text()
        doc = json.loads(text)
        assert text == json.dumps(doc, indent=1)
        assert doc["captures"] == [c.to_dict() for c in reversed(g.captures())], step
        assert doc["archived"] == [c.to_dict() for c in g.archived()], step
        assert doc["dives"] == g.dives() and doc["dive"] == g.dive
        assert doc["summary"] == sorted(c.image_index for c in g.summary())
        assert (doc["history_dropped"], doc["archived_dropped"]) == (g.history_dropped, g.archived_dropped)
