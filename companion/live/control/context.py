"""The explicit context the control handlers act on: the parts of the running companion a surface request may touch."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from companion.config import Config
from companion.live.enhance_worker import SelectiveStage
from companion.live.summary_keeper import SummaryKeeper
from companion.storage.store import Store
from companion.vision.gate import FrameGate
from companion.vision.pipeline import Pipeline
from vehicle.camera import status as st
from vehicle.camera.downlink import Downlink

STATUS_CHARS = 50
"""A STATUSTEXT line's length."""


@dataclass
class ControlContext:
    """Handed to each handler at construction; a handler reaches nothing else of the companion.

    Everything that changes the summary (the pipeline, the selective stage, the gates) is changed only inside a
    ``keeper.submit`` change; ``surface`` is None until the link is up (and without a vehicle link).
    """

    cfg: Config
    pipeline: Pipeline
    keeper: SummaryKeeper
    encoder: Any
    store: Store
    selective: SelectiveStage | None = None
    surface: Downlink | None = None

    @property
    def frame_gate(self) -> FrameGate:
        """The frame gate in force: with selective enhancement the one ahead of the raw scoring."""
        return self.selective.gate if self.selective is not None else self.pipeline.gate

    def say(self, text: str, severity: int = st.INFO) -> None:
        """One STATUSTEXT line to the surface (cut to fit), when a surface link is up."""
        if self.surface is not None:
            self.surface.event(text[:STATUS_CHARS], severity)

    def refuse(self, name: str, why: str, detail: str = "") -> None:
        """Say on the surface why ``name`` is refused (``why``, short) and refuse it (ValueError with ``detail``
        for the log); what was in force stays."""
        self.say(f"{name} refused: {why}", st.WARNING)
        raise ValueError(detail or why)
