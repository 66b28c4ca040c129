"""The autopilot events the companion sends to the surface: first contact is "up", a return after a loss "back"."""

from __future__ import annotations

from companion.config import load_config
from companion.live.control.context import ControlContext
from companion.live.control.notices import AutopilotNotice


class Events:
    """Stands in for the surface publisher (a real one needs a MAVLink link); records the event lines."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def event(self, text: str, severity: int) -> None:
        self.lines.append(text)


def test_first_contact_is_up_then_lost_then_back(tmp_path) -> None:
    cfg = load_config(None, overrides={"store": {"dir": str(tmp_path)}})
    ctx = ControlContext(cfg, pipeline=None, keeper=None, encoder=None, store=None, surface=Events())
    notice = AutopilotNotice(ctx)
    for alive in (True, False, True):
        notice(alive)
    assert ctx.surface.lines == ["Autopilot link up", "Autopilot link lost", "Autopilot link back"]
