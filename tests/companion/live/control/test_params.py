"""The MERL_* table: every configured value lies inside its own parameter's range (an item of docs/code-review.md)."""

from __future__ import annotations

from companion.config import Config, build_config
from companion.live.control.context import ControlContext
from companion.live.control.params import SERVED, TUNABLES, ParamHandler, default_params
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link
from vehicle.camera.downlink import Downlink


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


def test_the_link_parameters_are_applied_by_the_downlink_alone() -> None:
    """MERL_THUMB_B and MERL_LINK_BPS have one owner: the control table's handler leaves them to the Downlink
    (which applies every accepted value itself), so a change is applied once, not twice."""
    cfg = Config()
    assert [spec.name for spec in default_params(cfg)] == list(SERVED)
    assert not {"MERL_THUMB_B", "MERL_LINK_BPS"} & {t.name for t in TUNABLES}
    link = companion_link(free_udp_port())
    try:
        surface = Downlink(link, cfg.surface, params=default_params(cfg))
        ctx = ControlContext(cfg, pipeline=None, keeper=None, encoder=None, store=None, surface=surface)  # type: ignore[arg-type]
        handler = ParamHandler(ctx)
        handler("MERL_LINK_BPS", 5000)
        handler("MERL_THUMB_B", 4000)
        assert surface.budget.rate == cfg.surface.budget_bytes_per_s and surface.thumbnail_bytes == 2500
        surface.on_param_changed(handler, replay=False)
        assert surface.params.set("MERL_LINK_BPS", 5000) and surface.params.set("MERL_THUMB_B", 4000)
        assert surface.budget.rate == 5000 and surface.thumbnail_bytes == 4000
    finally:
        link.stop()
