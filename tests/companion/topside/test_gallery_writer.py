"""The writer thread that owns gallery.json: the latest state wins, ``wait`` means on disk, errors reach the end."""

from __future__ import annotations

import json
import threading

import pytest

from companion.topside import gallery_writer
from companion.topside.gallery_json import GalleryText, list_text
from companion.topside.gallery_writer import GalleryWriter


def _state(n: int) -> GalleryText:
    return GalleryText(updated=float(n), dive="a1", dives=("a1",), summary=(n,), captures=(), archived=list_text([]),
                       topics=(), history_dropped=n, archived_dropped=0)


def test_the_latest_state_is_on_disk_after_wait_and_states_waiting_are_replaced(tmp_path, monkeypatch):
    path = tmp_path / "gallery.json"
    writer = GalleryWriter(path)
    started, release = threading.Event(), threading.Event()
    real = gallery_writer.atomic_write

    def slow_write(target, data):
        started.set()
        release.wait(5)
        real(target, data)

    monkeypatch.setattr(gallery_writer, "atomic_write", slow_write)
    writer.hand_over(_state(1))
    assert started.wait(5)  # the thread is writing state 1: the caller went on
    for n in range(2, 50):
        writer.hand_over(_state(n))  # each replaces the one waiting
    release.set()
    writer.wait(5)
    assert json.loads(path.read_text())["history_dropped"] == 49
    assert writer.writes == 2  # 1, then only the latest


def test_a_write_through_waits_for_the_thread_so_the_last_written_is_the_latest(tmp_path):
    path = tmp_path / "gallery.json"
    writer = GalleryWriter(path)
    writer.hand_over(_state(1))
    writer.write_now(_state(2))
    writer.wait(5)
    assert json.loads(path.read_text())["history_dropped"] == 2


def test_a_failed_write_is_one_warning_and_raised_by_wait(tmp_path, caplog):
    writer = GalleryWriter(tmp_path / "missing" / "gallery.json")
    for n in range(3):
        writer.hand_over(_state(n))
        with pytest.raises(FileNotFoundError):
            writer.wait(5)
    assert sum("cannot write it" in r.getMessage() for r in caplog.records) == 1
    writer.path = tmp_path / "gallery.json"
    writer.hand_over(_state(7))
    writer.wait(5)
    assert json.loads(writer.path.read_text())["history_dropped"] == 7


def test_the_thread_ends_when_idle_and_starts_again(tmp_path, monkeypatch):
    monkeypatch.setattr(gallery_writer, "IDLE_S", 0.05)
    writer = GalleryWriter(tmp_path / "gallery.json")
    writer.hand_over(_state(1))
    writer.wait(5)
    thread = writer._thread
    assert thread is not None
    thread.join(5)
    assert not thread.is_alive() and writer._thread is None
    writer.hand_over(_state(2))
    writer.wait(5)
    assert json.loads((tmp_path / "gallery.json").read_text())["history_dropped"] == 2
