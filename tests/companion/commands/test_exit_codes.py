"""Exit codes follow the README's rule: 2 for bad arguments or configuration (a missing or unusable input among
them), 1 only when the work itself fails, or part of it (``score`` with some images unreadable). These used to exit
1 (or disagree between commands)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.conftest import run_merlion, shared_file

SURVEY = "survey/survey_480x270.mp4"


def one_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("merlion: error: "), proc.stderr
    return lines[0]


@pytest.mark.parametrize("command", ["summarize", "score"])
def test_a_folder_without_images_is_exit_2_and_names_the_subfolders_that_hold_them(tmp_path, command):
    dive = tmp_path / "dive"
    (dive / "images").mkdir(parents=True)
    (dive / "notes").mkdir()
    (dive / "labels.csv").write_text("file,fish\n")
    still = np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    for i in range(3):
        cv2.imwrite(str(dive / "images" / f"img{i}.png"), still)
    out = ["--out", str(tmp_path / "out")] if command == "summarize" else []
    proc = run_merlion(command, str(dive), *out, "--encoder", "visual", timeout=120)
    assert proc.returncode == 2
    assert one_line(proc).endswith("in this folder; images are in its subfolder images/ (3): name one")
    (dive / "images").rename(tmp_path / "elsewhere")
    proc = run_merlion(command, str(dive), *out, "--encoder", "visual", timeout=120)
    assert proc.returncode == 2 and one_line(proc).endswith(") in this folder")


def test_an_existing_output_folder_is_exit_2(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(out), "--encoder", "visual")
    assert proc.returncode == 2 and one_line(proc).endswith("already exists; use --force to replace it")


def test_clip_without_weights_is_a_configuration_error_exit_2(tmp_path):
    env = {"HOME": str(tmp_path), "HF_HOME": str(tmp_path / "hf"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    proc = run_merlion("summarize", str(shared_file(SURVEY)), "--out", str(tmp_path / "out"), "--encoder", "clip",
                       env=env)
    assert proc.returncode == 2 and "no CLIP weights for ViT-B-32" in one_line(proc)
    assert not (tmp_path / "out").exists()


def test_a_dive_profile_with_an_unknown_key_is_exit_2(tmp_path):
    profile = tmp_path / "dive.yaml"
    profile.write_text("legs:\n  - descend: {to_m: 3}\nbogus: 1\n")
    proc = run_merlion("sim-vehicle", "--profile", str(profile), "--connect", "udpout:127.0.0.1:9", timeout=60)
    assert proc.returncode == 2 and one_line(proc) == f"merlion: error: {profile}: unknown key 'bogus'"


@pytest.mark.parametrize("command", ["summarize", "score", "run", "demo"])
def test_a_text_file_named_mp4_is_exit_2_from_every_command(tmp_path, command):
    """The same input, the same exit: ``summarize`` and ``score`` exited 1 where ``run`` and ``demo`` exited 2."""
    notes = tmp_path / "notes.mp4"
    notes.write_text("not a video\n")
    out = tmp_path / "out"
    extra = {"summarize": [str(notes), "--out", str(out), "--encoder", "visual"],
             "score": [str(notes), "--encoder", "visual"],
             "run": ["--source", str(notes), "--store", str(out), "--mavlink", "none", "--duration", "20"],
             "demo": ["--source", str(notes), "--out", str(out), "--duration", "20"]}[command]
    proc = run_merlion(command, *extra, timeout=120)
    assert proc.returncode == 2, proc.stderr
    line = one_line(proc)
    assert str(notes) in line and ("cannot be opened as a video" in line or "cannot decode as an image" in line)
    assert not out.exists()
