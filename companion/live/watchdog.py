"""The systemd watchdog: ping while every stage moves, withhold the ping while one is stuck (systemd restarts us).

Once a second it also refreshes the status (the surface's 1 Hz values, systemd's STATUS= line) through ``tick``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from companion.live.health import Health
from companion.live.notify import Notifier

log = logging.getLogger(__name__)


class Watchdog(threading.Thread):
    def __init__(self, health: Health, notifier: Notifier, stop: threading.Event, tick: Callable[[], None]) -> None:
        super().__init__(name="health", daemon=True)
        self.health = health
        self.notifier = notifier
        self.stop_event = stop
        self.tick = tick
        self.pings = 0
        self.withheld = 0
        """Pings not sent because a stage was stuck."""
        self._stuck: list[str] = []
        self._last_ping = 0.0

    def run(self) -> None:
        ping_every = self.notifier.ping_interval_s or 1.0
        while not self.stop_event.wait(min(1.0, ping_every)):
            stuck = self.health.stuck()
            if stuck:
                self.withheld += 1
                if stuck != self._stuck:
                    log.warning("stage(s) %s stuck for over %.0f s: no watchdog ping until it moves again",
                                ", ".join(stuck), self.health.stall_after_s)
            elif self._stuck:
                log.warning("stage(s) %s moving again: watchdog pings resume", ", ".join(self._stuck))
            self._stuck = stuck
            if not stuck and time.monotonic() - self._last_ping >= ping_every:
                self.notifier.watchdog()
                self.pings += 1
                self._last_ping = time.monotonic()
            self.tick()
