"""The parameters a ground station may change live (MERL_*), with their ranges, taken from the configuration."""

from __future__ import annotations

from companion.config import Config
from vehicle.camera.params import ParamSpec


def gate_param(mode: str, threshold: float) -> float:
    """MERL_GATE's value: one number for the surface, 0 meaning the gate is off (gate.mode none)."""
    return 0.0 if mode == "none" else float(threshold)


def default_params(cfg: Config) -> list[ParamSpec]:
    """The tunable set, starting from the configuration (names at most 16 characters)."""
    return [
        ParamSpec("MERL_TAU_SS", cfg.queries.tau_ss, 0.0, 0.99,
                  doc="semantic pre-sampling threshold (0: no semantic gate)"),
        ParamSpec("MERL_TAU_SES", cfg.enhance.tau_ses, 0.01, 0.99, doc="threshold after enhancement"),
        ParamSpec("MERL_K", cfg.sampler.k, 1, 1000, integer=True, doc="summary size"),
        ParamSpec("MERL_THUMB_B", cfg.surface.thumbnail_bytes, 300, 65000, integer=True,
                  doc="thumbnail byte budget"),
        ParamSpec("MERL_LINK_BPS", cfg.surface.budget_bytes_per_s, 100, 1_000_000, integer=True,
                  doc="link budget, bytes/s"),
        ParamSpec("MERL_GATE", gate_param(cfg.gate.mode, cfg.gate.threshold), 0.0, 255.0,
                  doc="frame gate: 0 off, else the grey-level difference that gets a frame encoded"),
        ParamSpec("MERL_ENHANCE", 0 if cfg.enhance.mode == "none" else 1, 0, 1, integer=True,
                  doc="enhancer off (0) or on (1)"),
    ]


