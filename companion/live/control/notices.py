"""What the companion tells the surface on its own (not asked): the autopilot's heartbeat and the camera's state."""

from __future__ import annotations

import logging

from companion.live.control.context import ControlContext
from companion.sources.retrying import RetryingSource
from vehicle.camera import status as st

log = logging.getLogger(__name__)


def autopilot_notice(ctx: ControlContext, alive: bool) -> None:
    """The link's on_autopilot callback: logged, and said on the surface."""
    if alive:
        log.info("autopilot heartbeat back")
    else:
        log.warning("autopilot heartbeat lost; frames are tagged stale until it returns")
    ctx.say(*st.link_text(alive))


def source_notice(ctx: ControlContext, source: RetryingSource | None, state: str) -> None:
    """The camera source's on_state callback: lost, back again, or ended (the links keep serving)."""
    if state == "retrying":
        ctx.say(*st.camera_text(False))
    elif state == "running" and source is not None and source.failures:
        ctx.say(*st.camera_text(True))
    elif state == "ended":
        ctx.say("Source ended; still serving", st.NOTICE)
