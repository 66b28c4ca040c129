"""A bad argument is one line naming the subcommand and the option, exit 2, like every other bad input: not
argparse's whole usage first, and an unknown option is blamed on the subcommand it was given to."""

from __future__ import annotations

import pytest

from tests.conftest import run_merlion

CASES = {
    "bad --topic": (["summarize", "S", "--out", "W", "--topic", "fish"],
                    "merlion: error: summarize --topic: 'fish': expected NAME=POSITIVE[;NEGATIVE...] "
                    "(see merlion summarize --help)"),
    "bad -k": (["summarize", "S", "--out", "W", "-k", "abc"],
               "merlion: error: summarize -k/--k: invalid int value: 'abc' (see merlion summarize --help)"),
    "missing --out": (["summarize", "S"], "merlion: error: summarize --out/-o: required (see merlion summarize --help)"),
    "unknown option": (["summarize", "S", "--out", "W", "--bogus"],
                       "merlion: error: summarize --bogus: unknown option or extra argument "
                       "(see merlion summarize --help)"),
    "unknown option of a group's command": (["eval", "auroc", "--bogus"],
                                            "merlion: error: eval auroc --bogus: unknown option or extra argument "
                                            "(see merlion eval auroc --help)"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_bad_argument_is_one_line_naming_subcommand_and_option(tmp_path, name):
    args, line = CASES[name]
    proc = run_merlion(*[str(tmp_path / a) if a in ("S", "W") else a for a in args], timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [line], proc.stderr
    assert not (tmp_path / "W").exists()


def test_no_command_shows_help_and_exits_2():
    proc = run_merlion(timeout=60)
    assert proc.returncode == 2
    assert "summarize" in proc.stdout + proc.stderr
