"""The archive of earlier dives on its own: filing a dive away, the bounds, and the files that go with a capture."""

from __future__ import annotations

from companion.topside.capture import Capture
from companion.topside.dive_archive import DiveArchive


def _dive_with_thumbnails(root, dive: str, indices: range) -> list[Capture]:
    caps = []
    for i in indices:
        (root / "summary").mkdir(parents=True, exist_ok=True)
        (root / "summary" / f"{i}.jpg").write_bytes(b"jpg")
        caps.append(Capture(image_index=i, dive=dive, thumbnail=f"summary/{i}.jpg"))
    return caps


def test_filing_a_dive_moves_its_thumbnails_under_dives_and_takes_it_out_of_any_summary(tmp_path):
    archive = DiveArchive(tmp_path)
    caps = _dive_with_thumbnails(tmp_path, "a1", range(3))
    caps[2].in_summary = False
    caps[2].thumbnail = "removed/2.jpg"
    (tmp_path / "removed").mkdir()
    (tmp_path / "summary" / "2.jpg").rename(tmp_path / "removed" / "2.jpg")
    archive.file_away(caps, "a1")
    archive.start_dive("a1", "b2")
    assert [c.thumbnail for c in archive.captures] == ["dives/a1/summary/0.jpg", "dives/a1/summary/1.jpg",
                                                       "dives/a1/removed/2.jpg"]
    assert all(not c.in_summary for c in archive.captures)
    assert (tmp_path / "dives/a1/removed/2.jpg").read_bytes() == b"jpg"
    assert archive.dives == ["a1", "b2"] and archive.knows("a1") and not archive.knows("c3")


def test_a_capture_of_no_dive_is_filed_under_unknown(tmp_path):
    archive = DiveArchive(tmp_path)
    archive.file_away(_dive_with_thumbnails(tmp_path, None, range(1)), None)
    assert archive.captures[0].thumbnail == "dives/unknown/summary/0.jpg" and archive.captures[0].dive is None


def test_past_the_bound_the_first_archived_go_with_their_thumbnails_and_emptied_folders(tmp_path):
    archive = DiveArchive(tmp_path, max_archived=3)
    archive.file_away(_dive_with_thumbnails(tmp_path, "a1", range(2)), "a1")
    archive.file_away(_dive_with_thumbnails(tmp_path, "b2", range(3)), "b2")
    assert archive.bound("c3") is True
    assert [(c.dive, c.image_index) for c in archive.captures] == [("b2", 0), ("b2", 1), ("b2", 2)]
    assert archive.dropped == 2 and not (tmp_path / "dives/a1").exists()
    assert sorted(p.name for p in (tmp_path / "dives/b2/summary").iterdir()) == ["0.jpg", "1.jpg", "2.jpg"]
    assert archive.bound("c3") is False and archive.dropped == 2


def test_past_max_dives_the_oldest_ids_go_but_never_the_current_one(tmp_path):
    archive = DiveArchive(tmp_path, max_dives=3)
    archive.dives = ["cur", "a", "b", "c", "d"]
    assert archive.bound("cur") is True
    assert archive.dives == ["cur", "c", "d"]


def test_load_takes_what_gallery_json_kept(tmp_path):
    archive = DiveArchive(tmp_path)
    archive.load({"archived": [{"image_index": 4, "dive": "a1", "in_summary": False}], "dives": ["a1", "b2"],
                  "archived_dropped": 7})
    assert archive.captures[0].image_index == 4 and archive.dives == ["a1", "b2"] and archive.dropped == 7
    archive.load({})
    assert not archive.captures and archive.dives == [] and archive.dropped == 0


def test_full_frames_go_with_their_captures_and_the_folder_with_the_dives_last(tmp_path):
    archive = DiveArchive(tmp_path, max_archived=2)
    for dive in ("a1", "b2"):
        (tmp_path / "full" / dive).mkdir(parents=True)
        for name in ("0.jpg", "1.jpg", "99.jpg"):  # 99: a frame whose capture was forgotten while its dive was on
            (tmp_path / "full" / dive / name).write_bytes(b"full")
    archive.file_away(_dive_with_thumbnails(tmp_path, "a1", range(2)), "a1")
    archive.file_away(_dive_with_thumbnails(tmp_path, "b2", range(1)), "b2")
    archive.bound("c3")  # a1/0 goes: its full frame too, the rest of a1 stays
    assert sorted(p.name for p in (tmp_path / "full/a1").iterdir()) == ["1.jpg", "99.jpg"]
    archive.file_away(_dive_with_thumbnails(tmp_path, "b2", range(1, 2)), "b2")
    archive.bound("c3")  # a1's last capture goes: its whole folder
    assert not (tmp_path / "full/a1").exists()
    assert sorted(p.name for p in (tmp_path / "full/b2").iterdir()) == ["0.jpg", "1.jpg", "99.jpg"]


def test_the_current_dives_full_frames_stay_even_when_old_captures_of_its_id_go(tmp_path):
    archive = DiveArchive(tmp_path, max_archived=0)
    (tmp_path / "full/a1").mkdir(parents=True)
    (tmp_path / "full/a1/0.jpg").write_bytes(b"full")
    archive.file_away(_dive_with_thumbnails(tmp_path, "a1", range(1)), "a1")
    archive.bound("a1")  # the id came back and is current: full/a1 is the current dive's now
    assert (tmp_path / "full/a1/0.jpg").exists() and not archive.captures


def test_a_gallery_deletes_a_dives_full_frames_when_the_dive_leaves_the_archive(tmp_path):
    from companion.topside.gallery import Gallery

    g = Gallery(tmp_path, max_archived=2)
    g.use_dive("a1")
    g.announce(Capture(image_index=0))
    g.announce(Capture(image_index=1))
    full = g.add_full(1, b"full frame", "a1")
    g.use_dive("b2")
    g.announce(Capture(image_index=0))
    g.add_full(0, b"full frame", "b2")
    assert full.exists() and g.archived_dropped == 0
    g.use_dive("c3")  # a1's two and b2's one archived: a1's first goes, its full frame stays
    assert full.exists()
    g.announce(Capture(image_index=0))
    g.use_dive("d4")  # c3's one archived: a1's last goes, and full/a1 with it
    assert not (tmp_path / "full/a1").exists() and (tmp_path / "full/b2/0.jpg").exists()
