"""A query word the packaged encoder does not know is bad input: exit 2, one line naming where the query was set
(the option typed, or the file and its dotted key), as a bad config value is named."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import run_merlion, shared_file

WHY = "'blorptang' is not an English word that WordNet knows"
TOPICS = """queries:
  topics:
    - {name: fish, positive: underwater image with fish}
    - {name: odd, positive: a blorptang on the sea floor, negatives: [empty sea floor]}
"""


def _cfg(tmp_path: Path, text: str) -> str:
    path = tmp_path / "dive.yaml"
    path.write_text("encoder:\n  name: imagenet\n" + text)
    return str(path)


@pytest.mark.parametrize("case", ["--query", "--negative", "config positive", "config topic", "run topic",
                                  "environment"])
@pytest.mark.slow
def test_an_unknown_query_word_is_blamed_on_the_setting_that_gave_it(tmp_path, case):
    image = str(shared_file("suim/images/n_l_12_.jpg"))
    if case == "--query":
        proc = run_merlion("score", image, "--encoder", "imagenet", "--query", "a blorptang")
        where = "--query"
    elif case == "--negative":
        proc = run_merlion("score", image, "--encoder", "imagenet", "--query", "fish", "--negative", "blorptang")
        where = "--negative"
    elif case == "environment":  # over a file that sets a good query: the variable is to blame, not the file
        cfg = _cfg(tmp_path, "queries:\n  positive: underwater image with fish\n")
        proc = run_merlion("score", image, "--config", cfg, env={"MERLION__QUERIES__POSITIVE": "a blorptang"})
        where = "environment MERLION__QUERIES__POSITIVE"
    elif case == "config positive":
        cfg = _cfg(tmp_path, "queries:\n  positive: underwater image with blorptang\n")
        proc = run_merlion("summarize", image, "--out", str(tmp_path / "out"), "--config", cfg)
        where = f"{cfg}: queries.positive"
    else:
        cfg = _cfg(tmp_path, TOPICS)
        if case == "config topic":
            proc = run_merlion("summarize", image, "--out", str(tmp_path / "out"), "--config", cfg)
        else:
            proc = run_merlion("run", "--config", cfg, "--source", "synthetic://dive?seconds=2", "--mavlink", "none",
                               "--store", str(tmp_path / "store"))
        where = f"{cfg}: queries.topics.1.positive"
    assert proc.returncode == 2, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith(f"merlion: error: {where}: {WHY} (query "), line
    assert "near words: " in line
    assert not (tmp_path / "out").exists()
