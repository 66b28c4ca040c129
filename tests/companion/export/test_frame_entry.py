"""`merlion export` of a store whose summary.json has a damaged frame entry: one line naming the file, the entry and
the field, exit 2, nothing written and the store untouched (before: a traceback for a width of "abc", a score of
null, an index of "x" or 1e400 read as infinity)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from companion.config import StoreConfig
from companion.errors import UsageError
from companion.export.writer import export
from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame
from tests.conftest import run_merlion


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("store")
    store = Store(StoreConfig(dir=str(folder)))
    for i in range(3):
        image = np.random.default_rng(i).integers(0, 255, size=(48, 64, 3), dtype=np.uint8)
        frame = SummaryFrame(image_index=i, frame_index=i, time_s=float(i), capture_time=1_700_000_000.0 + i,
                             score=0.7, image=image, feature=np.ones(8, np.float32), topic="main")
        store.apply(SummaryEvent("added", frame, list(range(i + 1))), tags={"query": "fish"})
    return folder


def _damaged(store: Path, where: Path, change) -> Path:
    shutil.copytree(store, where)
    doc = json.loads((where / "summary.json").read_text())
    change(doc["frames"])
    (where / "summary.json").write_text(json.dumps(doc))
    return where


def _digest(folder: Path) -> str:
    return hashlib.sha256(b"".join(p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file())).hexdigest()


CASES = {
    "width": (lambda f: f[1].update(width="abc"), "width 'abc' is not a whole number of pixels"),
    "infinite width": (lambda f: f[1].update(width=1e400), "width inf is not a whole number of pixels"),
    "score": (lambda f: f[1].update(score=None), "score None is not a number"),
    "index": (lambda f: f[1].update(image_index="x"), "image_index 'x' is not a whole number"),
    "negative index": (lambda f: f[1].update(image_index=-1), "image_index -1 is not a whole number"),
    "no file": (lambda f: f[1].pop("file"), "frames[1]: no 'file'"),
    "file outside": (lambda f: f[1].update(file="../../etc/passwd"), "is not a path inside the folder"),
    "file a list": (lambda f: f[1].update(file=["a"]), "file ['a'] is not a path inside the folder"),
    "not an object": (lambda f: f.__setitem__(1, "frames/000001.jpg"), "frames[1]: not an object"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_damaged_entry_is_named_and_nothing_is_written(store: Path, tmp_path: Path, case: str) -> None:
    change, words = CASES[case]
    broken = _damaged(store, tmp_path / "broken", change)
    before = _digest(broken)
    out = tmp_path / "out.json"
    with pytest.raises(UsageError) as refused:
        export(broken, "coco", out)
    assert f"{broken / 'summary.json'}: frames[1]" in str(refused.value) and words in str(refused.value)
    assert not out.exists() and _digest(broken) == before


def test_the_command_prints_one_line_and_exits_2(store: Path, tmp_path: Path) -> None:
    broken = _damaged(store, tmp_path / "broken", lambda f: f[1].update(score="high"))
    done = run_merlion("export", str(broken), "--format", "csv", "--out", str(tmp_path / "o.csv"), timeout=60)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0] == (f"merlion: error: {broken / 'summary.json'}: frames[1] (frames/000001.jpg): score 'high' "
                        f"is not a number")
    assert not (tmp_path / "o.csv").exists()


def test_text_fields_of_another_kind_are_left_out_not_written_as_python(store: Path, tmp_path: Path) -> None:
    broken = _damaged(store, tmp_path / "broken", lambda f: f[1].update(topic={"a": 1}, tags={"query": ["x"]}))
    records = export(broken, "csv", tmp_path / "o.csv")
    assert [(r.frame, r.topic, r.query) for r in records] == [(0, "main", "fish"), (1, "", ""), (2, "main", "fish")]
