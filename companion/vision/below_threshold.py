"""A dive is never silently empty: while nothing passes a topic's semantic gate, its best frames stand in.

A query the footage never answers above ``tau_ss`` (deep-sea ROV footage and "fish", a threshold set too high)
used to leave an empty summary: the operator saw nothing and could not tell a quiet dive from a wrong query. Per
topic, this keeps the best-scoring frames seen since the last frame that passed, a few seconds apart so they are
not one moment; once nothing has passed for ``quiet_s`` seconds of footage (or at the end of a file) they enter
the summary marked ``below_threshold``, and a better one later replaces the worst. The first frame that does pass
displaces them all. The pipeline turns what this returns into summary events.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.sources.frame import Frame
from companion.vision.events import SummaryFrame
from vehicle.autopilot.pose import Pose

KEEP = 3
"""Stand-in frames per topic (at most the summary's K)."""
MIN_GAP_S = 2.0
"""Stand-ins closer in time than this are one moment: the better one is kept."""


def stand_in(frame: Frame, image: np.ndarray, score: float, feature: np.ndarray, pose: Pose | None,
             topic: str, raw: tuple[np.ndarray | None, float | None] = (None, None)) -> SummaryFrame:
    """A frame below the threshold as a summary frame (numbered when shown); ``image`` is what the summary
    shows, and ``raw`` the frame as captured and its ss_t when that image is an enhanced copy."""
    raw_image, raw_score = raw
    return SummaryFrame(image_index=-1, frame_index=frame.index, time_s=frame.time_s,
                        capture_time=frame.capture_time, score=score, image=image, feature=feature, pose=pose,
                        raw_image=raw_image, enhanced=raw_image is not None, topic=topic, below_threshold=True,
                        raw_score=raw_score)


@dataclass
class BestBelow:
    """One topic's stand-in frames: candidates (not in the summary) and those shown (in the summary)."""

    keep: int = KEEP
    min_gap_s: float = MIN_GAP_S
    since: float | None = None
    """Footage time (``time_s``) since which nothing has passed; None until a frame is seen."""
    candidates: list[SummaryFrame] = field(default_factory=list)
    shown: dict[int, SummaryFrame] = field(default_factory=dict)
    """Stand-ins in the summary, by image index."""

    def seen(self, time_s: float) -> None:
        if self.since is None:
            self.since = time_s

    def passed(self, time_s: float) -> list[SummaryFrame]:
        """A frame passed: the stand-ins leave (returned, for removal events) and the quiet period restarts."""
        gone = list(self.shown.values())
        self.shown.clear()
        self.candidates.clear()
        self.since = time_s
        return gone

    def consider(self, frame: SummaryFrame) -> bool:
        """Keep ``frame`` (not yet numbered) if it is among the best; True when it was kept."""
        near = [c for c in self.candidates if abs(c.time_s - frame.time_s) < self.min_gap_s]
        if near:
            if frame.score <= max(c.score for c in near):
                return False
            self.candidates = [c for c in self.candidates if c not in near]
        elif len(self.candidates) >= self.keep:
            worst = min(self.candidates, key=lambda c: c.score)
            if frame.score <= worst.score:
                return False
            self.candidates.remove(worst)
        self.candidates.append(frame)
        return True

    def quiet_for(self, time_s: float) -> float:
        return 0.0 if self.since is None else time_s - self.since

    def due(self, time_s: float, quiet_s: float) -> bool:
        """Whether the stand-ins should be in the summary now: shown already, or quiet for ``quiet_s``."""
        return bool(self.shown) or (self.since is not None and self.quiet_for(time_s) >= quiet_s)

    def to_show(self) -> tuple[list[SummaryFrame], list[SummaryFrame]]:
        """(candidates to add, shown frames to remove) so the summary shows exactly the current candidates."""
        want = {id(c) for c in self.candidates}
        gone = [f for f in self.shown.values() if id(f) not in want]
        for f in gone:
            del self.shown[f.image_index]
        shown = {id(f) for f in self.shown.values()}
        return [c for c in self.candidates if id(c) not in shown], gone

    def showing(self, frame: SummaryFrame) -> None:
        self.shown[frame.image_index] = frame
