"""What the companion tells the surface on its own (not asked): the autopilot's heartbeat and the camera's state."""

from __future__ import annotations

import logging

from companion.live.control.context import ControlContext
from companion.sources.retrying import RetryingSource
from vehicle.camera import status as st

log = logging.getLogger(__name__)


class AutopilotNotice:
    """The link's on_autopilot callback: logged, and said on the surface. The first contact is "up"; only a
    heartbeat after a loss is "back" (nothing was lost before the first one)."""

    def __init__(self, ctx: ControlContext) -> None:
        self.ctx = ctx
        self.seen = False

    def __call__(self, alive: bool) -> None:
        first = alive and not self.seen
        self.seen = self.seen or alive
        if first:
            log.info("autopilot heartbeat up")
        elif alive:
            log.info("autopilot heartbeat back")
        else:
            log.warning("autopilot heartbeat lost; frames are tagged stale until it returns")
        self.ctx.say(*st.link_text(alive, first))


def source_notice(ctx: ControlContext, source: RetryingSource | None, state: str) -> None:
    """The camera source's on_state callback: lost, back again, or ended (the links keep serving)."""
    if state == "retrying":
        ctx.say(*st.camera_text(False))
    elif state == "running" and source is not None and source.failures:
        ctx.say(*st.camera_text(True))
    elif state == "ended":
        ctx.say("Source ended; still serving", st.NOTICE)
