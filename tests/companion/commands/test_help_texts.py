"""Help texts say what each command does with an option: `score` makes no summary, and `eval auroc --query` is
a label name (unlike every other command's text query); `--holdout` warns that it is slow."""

from __future__ import annotations

from tests.conftest import run_merlion


def flat_help(*command: str) -> str:
    proc = run_merlion(*command, "--help", timeout=60)
    assert proc.returncode == 0, proc.stderr
    return " ".join(proc.stdout.split())


def test_score_topic_help_speaks_of_scores_not_summaries():
    text = flat_help("score")
    topic = text[text.index("--topic NAME=POSITIVE[;NEGATIVE...] follow"):]
    assert "summary" not in topic[:200] and "each image scored against each" in topic


def test_eval_auroc_help_says_query_is_a_label_and_holdout_is_slow():
    text = flat_help("eval", "auroc")
    assert "--query LABEL a label name, not a text query" in text
    assert "(slow: tens of minutes on 2 cores)" in text


def test_negative_help_says_what_a_lone_query_is_scored_against_and_the_encoders_do_it():
    """`--negative`'s help promised "a generic negative" while the packaged encoder scored the positive alone: the
    help now says both, and each encoder does what it says."""
    from companion.config import EncoderConfig
    from companion.vision.encoders.factory import make_encoder
    from companion.vision.presampler import GENERIC_NEGATIVE, PreSampler

    for command in (["summarize"], ["score"], ["archive"]):
        text = flat_help(*command)
        said = text[text.index("--negative TEXT"):]
        assert f"CLIP weighs the positive against the generic '{GENERIC_NEGATIVE}'" in said, command
        assert "the packaged encoder, which cannot read that phrase, scores the positive alone" in said, command
    packaged = PreSampler(make_encoder(EncoderConfig(name="imagenet")), "sharks")
    assert packaged.queries == ["sharks"]
    reads_any_text = PreSampler(make_encoder(EncoderConfig(name="visual")), "sharks")  # as CLIP: any phrase embeds
    assert reads_any_text.queries == ["sharks", GENERIC_NEGATIVE]
