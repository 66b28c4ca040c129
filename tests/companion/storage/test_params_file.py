"""params.json: saved and read back, migrated from an older version, a newer one refused and left untouched."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.storage.params_file import FILE_VERSION, ParamsFile
from companion.storage.versioned import NewerFileError, upgrade


def test_save_then_load_names_the_writer(tmp_path: Path) -> None:
    path = tmp_path / "params.json"
    ParamsFile(path, version="1.2.3").save({"MERL_K": 4.0})
    data = json.loads(path.read_text())
    assert data == {"version": FILE_VERSION, "written_by": "1.2.3", "params": {"MERL_K": 4.0}}
    assert ParamsFile(path).load() == {"MERL_K": 4.0}


def test_a_version_1_file_migrates_and_keeps_the_operators_values(tmp_path: Path) -> None:
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"version": 1, "params": {"MERL_TAU_SS": 0.42, "MERL_K": 9}}))
    assert ParamsFile(path).load() == {"MERL_TAU_SS": 0.42, "MERL_K": 9}
    assert json.loads(path.read_text())["version"] == 1, "reading never rewrites the file"


def test_a_newer_file_is_refused_naming_the_file_and_both_versions(tmp_path: Path) -> None:
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"version": FILE_VERSION + 1, "written_by": "9.0", "params": {"MERL_K": 3}}))
    before = path.read_bytes()
    with pytest.raises(NewerFileError) as err:
        ParamsFile(path, version="0.5").load()
    text = str(err.value)
    assert str(path) in text and f"version {FILE_VERSION + 1}" in text and f"version {FILE_VERSION} at most" in text
    assert "merlion 9.0" in text and "merlion 0.5" in text
    assert path.read_bytes() == before


@pytest.mark.parametrize("text", ["{broken", "[1, 2]", '{"version": "two", "params": {}}', '{"version": 2}',
                                  '{"version": 0, "params": {}}'])
def test_a_damaged_file_is_ignored_not_fatal(tmp_path: Path, text: str) -> None:
    path = tmp_path / "params.json"
    path.write_text(text)
    assert ParamsFile(path).load() == {}
    assert path.read_text() == text


def test_migrations_run_one_step_at_a_time_in_order() -> None:
    steps = {1: lambda d: {**d, "a": d["x"] * 2}, 2: lambda d: {**d, "b": d["a"] + 1}}
    assert upgrade("f", {"version": 1, "x": 5}, current=3, migrations=steps) == {"version": 3, "x": 5, "a": 10,
                                                                                 "b": 11}
    assert upgrade("f", {"version": 2, "a": 1}, current=3, migrations=steps)["b"] == 2
    with pytest.raises(ValueError, match="no migration from version 1"):
        upgrade("f", {"version": 1}, current=2, migrations={})
