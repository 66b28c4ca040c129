"""The pilot's shutter (MAV_CMD_IMAGE_START_CAPTURE): the current frame kept as the pilot's own summary frame.

The camera's ``Shutter.wire`` callback (``vehicle/camera/shutter.py``). It runs on the link's control worker, which must answer at once
(QGroundControl re-sends a command it got no ACK for within its timeout, and a re-sent press would keep a second
frame), so it only picks the frame: the newest one the camera gave, with the pose at its capture time. The
keeping itself (scoring, numbering, storing, announcing: ``Pipeline.capture`` inside a keeper change) runs on a
thread of its own, which then tells the shutter it is done, so the capture status turns idle again.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from companion.live.control.context import ControlContext
from companion.sources.frame import Frame
from vehicle.autopilot.pose import Pose
from vehicle.camera import status as st

log = logging.getLogger(__name__)

MAX_PILOT_FRAMES = 200
"""The pilot's frames the summary holds at most. They are never trimmed for room, and without a signing key
anyone on the link can press: past this a press is refused (TEMPORARILY_REJECTED, said on the surface) rather
than growing the summary and the store without end."""


class ShutterHandler:
    """``take(done)``: start keeping the newest frame; False when the camera gave none yet."""

    def __init__(self, ctx: ControlContext, latest: Callable[[], Frame | None],
                 pose_at: Callable[[float], Pose | None]) -> None:
        self.ctx = ctx
        self.latest = latest
        self.pose_at = pose_at
        self.taken: list[int] = []
        """Image indices the pilot's presses kept (this run)."""
        self.max_frames = MAX_PILOT_FRAMES

    def __call__(self, done: Callable[[bool], None]) -> bool:
        frame = self.latest()
        if frame is None:
            self.ctx.say("Shutter: no camera frame yet", st.WARNING)
            return False
        if sum(len(t.pilot) for t in self.ctx.pipeline.topics) >= self.max_frames:
            self.ctx.say(f"Shutter: {self.max_frames} pilot frames held", st.WARNING)
            return False
        threading.Thread(target=self._keep, args=(frame, done), name="shutter", daemon=True).start()
        return True

    def _keep(self, frame: Frame, done: Callable[[bool], None]) -> None:
        ok = False
        try:
            pose = self.pose_at(frame.capture_time)
            events = self.ctx.keeper.submit(lambda: self.ctx.pipeline.capture(frame, pose))
            ok = bool(events)
            if ok:
                self.taken.append(events[0].frame.image_index)
                log.info("pilot's capture: image %d (frame %d)", events[0].frame.image_index, frame.index)
            else:
                self.ctx.say("Shutter: image indices used up", st.WARNING)
        except Exception as err:  # noqa: BLE001 - the press is answered already; the pilot hears why it failed
            log.exception("pilot's capture failed")
            self.ctx.say(f"Shutter failed: {err}", st.WARNING)
        finally:
            done(ok)
