"""The STATUSTEXT that says a topic's summary shows stand-ins: nothing has passed its threshold for a while.

A dive must never be silently empty (``companion.vision.below_threshold``): when a topic's first stand-in frame
enters the summary, the operator is told once, in one line, so an empty-looking dive reads as "the query finds
nothing here" and can be re-queried or marked; the next time a real frame enters, the notice re-arms.
"""

from __future__ import annotations

from companion.vision.events import SummaryEvent

WIDTH = 50


class QuietNotice:
    """Says once per quiet period per topic that it shows its best frames, below the threshold."""

    def __init__(self, quiet_s: float) -> None:
        self.quiet_s = quiet_s
        self._told: set[str] = set()

    def line_for(self, event: SummaryEvent) -> str | None:
        """The line to send for this summary event, if any."""
        if event.kind != "added":
            return None
        topic = event.frame.topic
        if not event.frame.below_threshold:
            self._told.discard(topic)
            return None
        if topic in self._told:
            return None
        self._told.add(topic)
        return f"{topic}: none passed in {self.quiet_s:g}s; best shown"[:WIDTH]
