"""The MERL_* table: every configured value lies inside its own parameter's range (an item of docs/code-review.md)."""

from __future__ import annotations

from companion.config import build_config
from companion.live.control.params import TUNABLES, default_params


def test_a_configured_value_beyond_the_usual_range_is_inside_its_parameters_range() -> None:
    cfg = build_config({"queries": {"tau_ss": 0.995}, "surface": {"budget_bytes_per_s": 2_000_000}})
    specs = {spec.name: spec for spec in default_params(cfg)}
    assert specs["MERL_TAU_SS"].value == 0.995 and specs["MERL_TAU_SS"].maximum == 0.995
    assert specs["MERL_LINK_BPS"].value == 2_000_000 and specs["MERL_LINK_BPS"].maximum == 2_000_000
    usual = {t.name: (t.minimum, t.maximum) for t in TUNABLES}
    assert (specs["MERL_K"].minimum, specs["MERL_K"].maximum) == usual["MERL_K"]  # in range: unchanged
    for spec in specs.values():
        assert spec.minimum <= spec.value <= spec.maximum, spec.name
        assert len(spec.name) <= 16
