"""The configuration schema: defaults, overrides and one-line errors that name the key."""

from __future__ import annotations

import pytest

from companion.config import Config, ConfigError, load_config


def test_defaults_are_complete_and_valid():
    cfg = load_config(environ={})
    assert cfg.sampler.k == 6
    assert cfg.queries.positive == "underwater image with fish"
    assert cfg.mavlink.component_id == 100


def test_tau_ss_zero_is_accepted_as_no_gate_but_tau_ses_zero_is_not(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("queries:\n  tau_ss: 0\n")
    assert load_config(f, environ={}).queries.tau_ss == 0.0
    f.write_text("enhance:\n  tau_ses: 0\n")
    with pytest.raises(ConfigError, match="enhance.tau_ses"):
        load_config(f, environ={})


def test_percentage_threshold_is_read_as_fraction(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("queries:\n  tau_ss: 40\n")
    assert load_config(f, environ={}).queries.tau_ss == pytest.approx(0.4)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("sampler:\n  kk: 3\n", "sampler.kk: unknown key"),
        ("sampler:\n  k: many\n", "sampler.k"),
        ("sampler:\n  k: 0\n", "sampler.k"),
        ("queries:\n  tau_ss: 150\n", "queries.tau_ss"),
        ("mavlink:\n  system_id: 255\n", "mavlink.system_id"),
        ("[1, 2]\n", "top level must be a mapping"),
        ("sampler: {k: [\n", "line"),
        ("sampler:\n  k: 3\nsampler:\n  k: 4\n", "line 3: key 'sampler' is given twice"),  # the last one won
        ("sampler:\n  k: 3\n  k: 4\n", "line 3: key 'k' is given twice"),
        ("queries:\n  positive: ''\n", "queries.positive: String should have at least 1 character"),
        ("queries:\n  topics: [{name: a, positive: fish, negatives: ['']}]\n", "queries.topics.0.negatives.0"),
    ],
)
def test_bad_values_name_file_and_key(tmp_path, text, needle):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f, environ={})
    message = str(info.value)
    assert "\n" not in message
    assert str(f) in message
    assert needle in message


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "nope.yaml", environ={})


def test_a_binary_file_is_named_not_a_traceback(tmp_path):
    f = tmp_path / "photo.jpg"
    f.write_bytes(b"\xff\xd8\xff\xe0 not yaml")
    with pytest.raises(ConfigError, match=r"photo\.jpg: not a UTF-8 text file \(byte 0\)"):
        load_config(f, environ={})


def test_environment_and_overrides_win_in_order(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("sampler:\n  k: 4\nsurface:\n  budget_bytes_per_s: 3000\n")
    cfg = load_config(
        f,
        environ={"MERLION__SAMPLER__K": "9", "MERLION__QUERIES__NEGATIVES": "[a, b]"},
        overrides={"surface": {"budget_bytes_per_s": 5000}},
    )
    assert cfg.sampler.k == 9
    assert cfg.queries.negatives == ["a", "b"]
    assert cfg.surface.budget_bytes_per_s == 5000


def test_bad_environment_value_is_named():
    with pytest.raises(ConfigError, match="sampler.k"):
        load_config(environ={"MERLION__SAMPLER__K": "lots"})


def test_model_is_typed():
    assert isinstance(Config().sampler.k, int)
