"""atomic_write: the target holds the old or the new content, never a temp file or half of one."""

from __future__ import annotations

import pytest

from companion.atomic_write import TMP_PREFIX, atomic_write


def test_replaces_content_and_leaves_no_temp_file(tmp_path):
    target = tmp_path / "a.json"
    atomic_write(target, b"old")
    atomic_write(target, "new \u00e9")
    assert target.read_text(encoding="utf-8") == "new \u00e9"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_failed_write_keeps_old_file_and_cleans_up(tmp_path):
    target = tmp_path / "a.json"
    atomic_write(target, b"old")
    with pytest.raises(TypeError):
        atomic_write(target, 42)  # type: ignore[arg-type]  # fails inside the write, after the temp file exists
    assert target.read_bytes() == b"old"
    assert not list(tmp_path.glob(f"{TMP_PREFIX}*"))
