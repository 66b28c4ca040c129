"""Command-line numbers: NaN, infinities and out-of-range values are one-line usage errors (exit 2)."""

from __future__ import annotations

import pytest

from companion.commands.arg_checks import require_non_negative, require_positive
from companion.errors import UsageError
from tests.conftest import run_merlion, shared_file


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_require_positive_refuses(value: float) -> None:
    with pytest.raises(UsageError, match=r"^--duration .*: must be positive$"):
        require_positive("--duration", value)


def test_require_positive_and_non_negative_accept() -> None:
    require_positive("--duration", 0.5)
    require_positive("--duration", None)  # not given
    require_non_negative("--start", 0.0)
    with pytest.raises(UsageError, match="must be zero or more"):
        require_non_negative("--start", float("nan"))


@pytest.mark.parametrize("args, message", [
    (("run", "--duration", "nan"), "merlion: error: --duration nan: must be positive"),
    (("sim-vehicle", "--connect", "udpout:127.0.0.1:9", "--fluid-density", "-5"),
     "merlion: error: --fluid-density -5.0: must be positive"),
    (("bench", "enhance", "--seconds", "nan"), "merlion: error: --seconds nan: must be positive"),
    (("eval", "labels", "--labels", "none.csv", "--summary", "1", "--label-fps", "nan"),
     "merlion: error: --label-fps nan: must be positive"),
])
def test_commands_refuse_nan_and_negative_numbers(args: tuple[str, ...], message: str) -> None:
    done = run_merlion(*args, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [message]


@pytest.mark.parametrize("command", [("telemetry", "--connect", "udpout:no-such-host.invalid:14550"),
                                     ("surface", "--connect", "udpin:no-such-host.invalid:14550")])
def test_an_unresolvable_host_fails_at_once_naming_it(tmp_path, command):
    proc = run_merlion(*command, "--out", str(tmp_path / "g"), timeout=60) if command[0] == "surface" else \
        run_merlion(*command, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("merlion: error:")]
    assert len(lines) == 1 and lines[0].startswith(f"merlion: error: --connect {command[2]}: cannot resolve host "
                                                   "'no-such-host.invalid' ("), proc.stderr
    assert "open" not in proc.stdout and not (tmp_path / "g").exists()


@pytest.mark.parametrize("args, message", [
    (("--query", ""), "merlion: error: --query: empty (name a thing to look for, e.g. 'fish')"),
    (("--query", "a" * 301), "merlion: error: --query: queries.positive: String should have at most 300 characters"),
    (("--query", "fish", "--negative", ""),
     "merlion: error: --negative: empty (name what the wanted frames do not show, or leave it out)"),
])
def test_an_empty_or_overlong_query_is_one_line_naming_the_option(tmp_path, args, message) -> None:
    image = tmp_path / "frame.png"
    image.write_bytes(b"")  # never read: the query is refused first
    done = run_merlion("score", *args, str(image), timeout=60)
    assert done.returncode != 0
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), done.stderr


@pytest.mark.parametrize("out, message", [
    ("afile/head.json", "afile is a file, not a folder"),
    (".", "is a folder (give the file's name)"),
])
@pytest.mark.parametrize("option", ["--out", "--scene-out"])
def test_train_head_refuses_an_output_it_could_not_write_before_any_training(tmp_path, out, message, option):
    (tmp_path / "afile").write_text("kept\n")
    done = run_merlion("eval", "train-head", "--data", str(tmp_path / "no-data-needed"), option, str(tmp_path / out),
                       timeout=60)
    assert done.returncode != 0
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(message), done.stderr
    assert (tmp_path / "afile").read_text() == "kept\n"


@pytest.mark.parametrize("k", ["94", "1000000000000"])
def test_eval_labels_refuses_an_oracle_larger_than_the_labelled_frames(k) -> None:
    labels = shared_file("survey/survey_480x270_labels.csv")
    done = run_merlion("eval", "labels", "--labels", str(labels), "--summary", "10", "20", "--fps", "10", "--k", k,
                       timeout=60)  # 10**12 never finished before
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"merlion: error: --k {k}: must be from 1 to the 93 labelled frames of {labels}"]


@pytest.mark.slow
def test_options_that_would_be_ignored_or_found_late_are_refused_at_once(tmp_path) -> None:
    (tmp_path / "afile").write_text("kept\n")
    cases = [
        (("eval", "auroc", "video.mp4", "--labels", "l.csv", "--marks", "-2"),
         "merlion: error: --stress, --sweep, --holdout, --marks and --orders go with --data"),  # was ignored
        (("eval", "auroc", "video.mp4", "--labels", "l.csv", "--orders", "5"),
         "merlion: error: --stress, --sweep, --holdout, --marks and --orders go with --data"),
        (("eval", "auroc", "--data", str(tmp_path / "nowhere"), "--holdout", "--orders", "0"),
         "merlion: error: --orders 0: must be 1 to 50"),
        (("eval", "auroc", "--data", str(tmp_path / "nowhere"), "--orders", "5"),
         "merlion: error: --orders goes with --holdout or --marks (the figures that depend on the frame order)"),
        (("eval", "auroc", "--data", str(tmp_path / "nowhere"), "--marks", "0"),
         "merlion: error: --marks 0: must be 1 or more"),  # before loading the data, not after
        (("summarize", str(tmp_path), "--out", str(tmp_path / "afile" / "x")),
         f"merlion: error: {tmp_path / 'afile' / 'x'}: {tmp_path / 'afile'} is a file, not a folder"),
    ]
    for args, message in cases:
        done = run_merlion(*args, timeout=60)
        assert done.returncode != 0
        assert done.stderr.strip().splitlines() == [message], done.stderr
    assert (tmp_path / "afile").read_text() == "kept\n"
