"""Thumbnail files (``companion.topside.thumbnail_files``): a path read back from gallery.json stays inside DIR."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from companion.topside.capture import Capture
from companion.topside.thumbnail_files import forget_thumbnail, inside, move_thumbnail


@pytest.fixture
def layout(tmp_path: Path) -> tuple[Path, Path]:
    root = tmp_path / "gallery"
    (root / "summary").mkdir(parents=True)
    (root / "summary" / "7.jpg").write_bytes(b"thumb")
    outside = tmp_path / "precious.jpg"
    outside.write_bytes(b"not the gallery's")
    os.symlink(outside, root / "summary" / "link.jpg")
    return root, outside


@pytest.mark.parametrize("rel", ["../precious.jpg", "ABS", "summary/../../precious.jpg", "summary/link.jpg", ""])
def test_a_thumbnail_path_leading_out_of_the_gallery_is_never_deleted_nor_moved(layout, rel):
    root, outside = layout
    rel = str(outside) if rel == "ABS" else rel
    assert inside(root, rel) is None
    forget_thumbnail(root, Capture(image_index=1, thumbnail=rel or None))
    cap = Capture(image_index=2, thumbnail=rel or None)
    move_thumbnail(root, cap, "dives/d1")
    assert outside.read_bytes() == b"not the gallery's" and cap.thumbnail is None
    assert not (root / "dives" / "d1" / "precious.jpg").exists()


def test_a_thumbnail_inside_the_gallery_is_moved_and_then_deleted(layout):
    root, _ = layout
    cap = Capture(image_index=7, thumbnail="summary/7.jpg")
    move_thumbnail(root, cap, "dives/d1")
    assert cap.thumbnail == "dives/d1/7.jpg" and (root / "dives" / "d1" / "7.jpg").read_bytes() == b"thumb"
    forget_thumbnail(root, cap)
    assert not (root / "dives" / "d1").exists()  # the dive folder it left empty goes too
