"""Small helpers the vision tests share (plain functions, imported; fixtures live in conftest.py)."""

from __future__ import annotations

import csv
import os

from tests.conftest import shared_file


def run(pipe, frames, batch=8):
    """Frames through a Pipeline in batches: every FrameResult and event, in order."""
    results, events = [], []
    for start in range(0, len(frames), batch):
        out = pipe.process(frames[start:start + batch])
        results += out.results
        events += out.events
    return results, events


def replay_events(events) -> list[int]:
    """Apply a pipeline's summary events in order and return the image indices held at the end; after every
    removal what is held is exactly the summary that event carries (an added frame's list already leaves out
    what its own arrival trims, so only removals are compared)."""
    held: list[int] = []
    for ev in events:
        if ev.kind == "added":
            held.append(ev.frame.image_index)
        else:
            held.remove(ev.frame.image_index)
        assert sorted(held) == sorted(ev.summary) or ev.kind == "added"
    return held


def resident_kb_of(path: str) -> int:
    """Resident kB of this process's mappings of ``path`` (/proc/self/smaps)."""
    target, inside, total = os.path.realpath(path), False, 0
    with open("/proc/self/smaps", encoding="utf-8") as smaps:
        for line in smaps:
            head = line.split()
            if "-" in head[0] and len(head) >= 5 and not head[0].endswith(":"):
                inside = len(head) == 6 and os.path.realpath(head[5]) == target
            elif inside and head[0] == "Rss:":
                total += int(head[1])
    return total


def survey_marks(frames, n=3):
    """The first ``n`` fish and ``n`` empty frames of the survey (its labels), as marks' images."""
    with open(shared_file("survey/survey_480x270_labels.csv"), newline="") as fh:
        fish = {int(row["frame_index"]): int(row["fish_present"]) for row in csv.DictReader(fh)}
    like = [f.image for f in frames if fish[f.index]][:n]
    unlike = [f.image for f in frames if not fish[f.index]][:n]
    assert len(like) == len(unlike) == n
    return like, unlike
