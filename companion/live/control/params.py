"""The MERL_* parameters a ground station may change live: the whole table, and the handler that applies them.

Each row says the name (16 characters at most), the range, the value the configuration starts it at, and how a
change is applied: every row changes the pipeline, so the summary keeper's thread applies it between two batches
(a smaller MERL_K trims the summary; the trims are stored and announced in the same change). The surface link's
own parameters (MERL_THUMB_B, MERL_LINK_BPS) are not rows here: the ``Downlink`` defines and applies them
(vehicle/camera/link_params.py); ``SERVED`` only places them among these on the wire. How they persist is the same
for all: ``ParamServer`` (vehicle/camera/params.py) hands every accepted value to ``ParamsFile.save`` (the store's
params.json, written crash-safely) and the next start replays what differs from the configuration through this
same handler. A row's ``check`` may refuse a value before anything changes (ValueError, said on the surface).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Literal

from companion.config import Config
from companion.live.control.context import ControlContext
from companion.vision.events import SummaryEvent
from vehicle.camera.link_params import LINK_BPS, THUMB_B, link_params
from vehicle.camera.params import ParamSpec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Tunable:
    name: str
    minimum: float
    maximum: float
    start: Callable[[Config], float]
    """The value before any PARAM_SET: from the configuration."""
    apply: Callable[[ControlContext, float], list[SummaryEvent] | None]
    applied_by: Literal["summary"]
    """summary: a change run by the summary keeper's thread (the only kind: the link's own are the Downlink's)."""
    integer: bool = False
    doc: str = ""
    check: Callable[[ControlContext, float], None] | None = None
    """Refuses a value (ValueError) before anything changes."""

    def spec(self, cfg: Config) -> ParamSpec:
        """The parameter as served; its range widened to take in the configured value (``ParamSpec.around``)."""
        return ParamSpec.around(self.name, self.start(cfg), self.minimum, self.maximum, integer=self.integer,
                                doc=self.doc)


def gate_param(mode: str, threshold: float) -> float:
    """MERL_GATE's value: one number for the surface, 0 meaning the gate is off (gate.mode none)."""
    return 0.0 if mode == "none" else float(threshold)


# ---- how each one is applied (summary rows run inside a keeper change) ----------------------------------------
def _tau_ss(ctx: ControlContext, value: float) -> None:
    sel = ctx.selective
    if sel is not None:
        sel.raw.tau_ss = value  # every topic's raw gate
        if not sel.on:
            ctx.pipeline.tau_ss = value
    else:
        ctx.pipeline.tau_ss = value


def _tau_ses(ctx: ControlContext, value: float) -> None:
    ctx.pipeline.tau_ses = value
    if ctx.selective is not None and ctx.selective.on:
        ctx.pipeline.tau_ss = value  # the gate on enhanced frames


def _k(ctx: ControlContext, value: float) -> list[SummaryEvent]:
    return ctx.pipeline.set_k(int(value))


def _gate(ctx: ControlContext, value: float) -> None:
    """0: the frame gate off; otherwise its difference threshold in grey levels."""
    gate = ctx.frame_gate
    gate.mode = "difference" if value > 0 else "none"
    gate.threshold = max(0.0, float(value))


def _gate_gap(ctx: ControlContext, value: float) -> None:
    ctx.frame_gate.max_gap_s = float(value)


def _enhance(ctx: ControlContext, value: float) -> None:
    if ctx.selective is not None:
        ctx.selective.on = bool(value)
        ctx.selective.sync_gates()
    else:  # enhance.mode always: every frame enhanced, or none
        ctx.pipeline.enhance_mode = "always" if value else "none"


def _check_enhance(ctx: ControlContext, value: float) -> None:
    """MERL_ENHANCE=1 needs an enhancer, loaded at start only when enhance.mode asks for one: refuse, and say why
    on the surface, rather than accept a value that changes nothing."""
    if value and ctx.cfg.enhance.mode == "none":
        ctx.refuse("MERL_ENHANCE", "enhance.mode is none", "enhance.mode is none (no enhancer loaded); set "
                   "enhance.mode: selective or always and restart")


TUNABLES: tuple[Tunable, ...] = (
    Tunable("MERL_TAU_SS", 0.0, 0.99, lambda c: c.queries.tau_ss, _tau_ss, "summary",
            doc="semantic pre-sampling threshold (0: no semantic gate)"),
    Tunable("MERL_TAU_SES", 0.01, 0.99, lambda c: c.enhance.tau_ses, _tau_ses, "summary",
            doc="threshold after enhancement"),
    Tunable("MERL_K", 1, 1000, lambda c: c.sampler.k, _k, "summary", integer=True, doc="summary size"),
    Tunable("MERL_GATE", 0.0, 255.0, lambda c: gate_param(c.gate.mode, c.gate.threshold), _gate, "summary",
            doc="frame gate: 0 off, else the grey-level difference that gets a frame encoded"),
    Tunable("MERL_GATE_GAP", 0.1, 600.0, lambda c: c.gate.max_gap_s, _gate_gap, "summary",
            doc="frame gate: seconds after the last encoded frame when a frame is encoded whatever it shows"),
    Tunable("MERL_ENHANCE", 0, 1, lambda c: 0 if c.enhance.mode == "none" else 1, _enhance, "summary",
            integer=True, doc="enhancer off (0) or on (1)", check=_check_enhance),
)


SERVED: tuple[str, ...] = ("MERL_TAU_SS", "MERL_TAU_SES", "MERL_K", THUMB_B, LINK_BPS, "MERL_GATE", "MERL_GATE_GAP",
                           "MERL_ENHANCE")
"""Every parameter of the companion in wire order (PARAM_VALUE's param_index; kept as ground stations know it)."""


def default_params(cfg: Config) -> list[ParamSpec]:
    """The companion's parameters as the protocol serves them, starting from the configuration: the rows here and
    the surface link's own, in ``SERVED`` order."""
    specs = {t.name: t.spec(cfg) for t in TUNABLES} | {s.name: s for s in link_params(cfg.surface)}
    return [specs[name] for name in SERVED]


class ParamHandler:
    """``ParamServer``'s on_change callback: ValueError refuses the value (the ground station is echoed the old
    one); a row waits for the keeper's thread to apply it, so the echo follows the change. A name that is not a
    row (the Downlink's own) is left to its owner."""

    def __init__(self, ctx: ControlContext, table: tuple[Tunable, ...] = TUNABLES) -> None:
        self.ctx = ctx
        self.table: Mapping[str, Tunable] = {t.name: t for t in table}

    def __call__(self, name: str, value: float) -> None:
        tunable = self.table.get(name)
        if tunable is None:
            return
        if tunable.check is not None:
            tunable.check(self.ctx, value)
        self.ctx.keeper.submit(lambda: tunable.apply(self.ctx, value))

    def restore(self, restored: Mapping[str, float], fallback: Callable[[str], None]) -> None:
        """Apply what the operator set before the restart; a value refused now is logged and ``fallback(name)``
        puts the configured one back in force (e.g. MERL_ENHANCE after enhance.mode became none)."""
        for name, value in restored.items():
            try:
                self(name, value)
            except ValueError as err:
                log.warning("saved parameter %s=%g not applied: %s", name, value, err)
                fallback(name)
