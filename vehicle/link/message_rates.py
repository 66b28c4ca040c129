"""Ask the autopilot for the telemetry rates the companion needs, and keep them.

When the autopilot is found (and again after it was lost) the keeper first listens ``listen_s`` (1 s): a message
already arriving at 80 % or more of the wanted rate is left as it is, never asked for, so the companion neither
lowers a rate a ground station raised (the last request wins for every listener on the router) nor adds requests
that change nothing. The others get MAV_CMD_SET_MESSAGE_INTERVAL (ArduPilot 4.0+), per message, with its
COMMAND_ACK checked; an autopilot that answers UNSUPPORTED (or never answers) gets the legacy REQUEST_DATA_STREAM
for the stream holding that message. The ground station may change the same rates later, so the rates that
actually arrive are watched, and a message
arriving at less than half the asked rate is asked for again, with exponential back-off (grace_s, then 2, 4, 8, ...
times it, capped at backoff_max_s), so a message the vehicle cannot produce costs a few bytes a minute, not a
flood. A message that has not arrived once after ``missing_after`` requests is declared missing, once: logged and
passed to ``on_missing`` (an ArduSub without a position source, a DVL or USBL, accepts the request for
LOCAL_POSITION_NED and never sends it). It is asked for on the same back-off after that; when it arrives the
declaration is lifted. After an autopilot reboot (heartbeat lost, then found)
everything is asked for again.

All the bookkeeping belongs to the rates thread: the receive thread only queues when each message arrived, and the
link's "found again" only queues a reset; the rates thread takes both from its inbox at each wake. Other threads
read what it last published (``observed_hz``), never its working state.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.link.connection import MavLink

log = logging.getLogger(__name__)

# The REQUEST_DATA_STREAM group ArduSub puts each message in (the fallback for old firmware).
STREAM_OF: dict[str, int] = {
    "SCALED_PRESSURE2": mav2.MAV_DATA_STREAM_RAW_SENSORS,
    "SYS_STATUS": mav2.MAV_DATA_STREAM_EXTENDED_STATUS,
    "GLOBAL_POSITION_INT": mav2.MAV_DATA_STREAM_POSITION,
    "LOCAL_POSITION_NED": mav2.MAV_DATA_STREAM_POSITION,
    "ATTITUDE": mav2.MAV_DATA_STREAM_EXTRA1,
    "VFR_HUD": mav2.MAV_DATA_STREAM_EXTRA2,
    "SYSTEM_TIME": mav2.MAV_DATA_STREAM_EXTRA3,
    "BATTERY_STATUS": mav2.MAV_DATA_STREAM_EXTRA3,
}
LEAVE_SHARE = 0.8
"""A message already arriving at this share of the wanted rate or more when the autopilot is found is not asked for."""
_RESET = None
"""In the inbox: the autopilot was found (again); listen, then ask anew for what falls short."""


class RateKeeper:
    """Requests ``wanted`` (message name -> Hz) from the link's autopilot and re-requests what falls short."""

    def __init__(
        self,
        link: MavLink,
        wanted: dict[str, float],
        *,
        ack_timeout_s: float = 1.0,
        retries: int = 2,
        window_s: float = 5.0,
        grace_s: float = 3.0,
        backoff_max_s: float = 60.0,
        missing_after: int = 3,
        listen_s: float = 1.0,
        on_missing: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.link = link
        self.wanted = {name: hz for name, hz in wanted.items() if hz > 0}
        for name in self.wanted:
            if not hasattr(mav2, f"MAVLINK_MSG_ID_{name}"):
                raise ValueError(f"unknown MAVLink message {name!r}")
        self.ack_timeout_s = ack_timeout_s
        self.retries = retries
        self.window_s = window_s
        self.grace_s = grace_s
        self.backoff_max_s = backoff_max_s
        self.missing_after = missing_after
        self.listen_s = listen_s
        self.on_missing = on_missing
        self.clock = clock
        self.missing: set[str] = set()
        """Messages asked for ``missing_after`` times that never arrived."""
        self._arrived: set[str] = set()
        self.method: dict[str, str] = {}
        """How each message was last asked for: interval | data_stream, or as_found (it already arrived at
        LEAVE_SHARE of the wanted rate or more when the autopilot was found, so it was not asked for)."""
        self.requests: dict[str, int] = dict.fromkeys(self.wanted, 0)
        self.acks: dict[str, int] = {}
        """The last COMMAND_ACK result per message (MAV_RESULT_*)."""
        self._arrivals: dict[str, deque[float]] = {name: deque() for name in self.wanted}
        self._inbox: queue.SimpleQueue[tuple[str, float] | None] = queue.SimpleQueue()
        """(message, arrival time) from the receive thread, or _RESET: drained by the rates thread alone."""
        self._published: tuple[float, dict[str, tuple[float, ...]]] = (clock(), {})
        """(when, arrival times in the window then), as the rates thread last saw them: replaced whole, read by any
        thread. Rates are counted up to ``when``, not up to the reader's now, or a reader a second after the last
        wake (or after the keeper stopped) would count a window missing its last second."""
        self._asked_at: dict[str, float] = {}
        self._backoff: dict[str, float] = {}
        self._check_at: dict[str, float] = {}  # when each asked-for message is next looked at
        self._listen_from: float | None = None  # when the autopilot was last found: what arrives since is judged
        self._ack_cv = threading.Condition()
        self._last_ack: tuple[int, int] | None = None
        self._ack_serial = 0
        self._interval_supported = True
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._unsubs: list[Callable[[], None]] = []

    def start(self) -> None:
        self._unsubs = [
            self.link.subscribe(self._on_message, [*self.wanted, "COMMAND_ACK"]),
        ]
        self.link.on_autopilot(self._on_autopilot)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mavlink-rates", daemon=True)
        self._thread.start()
        if self.link.autopilot_alive:  # found before we listened: listen now
            self._inbox.put(_RESET)
            self._wake.set()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        for unsub in self._unsubs:
            unsub()
        if self._thread is not None:
            self._thread.join(timeout=5)
            if not self._thread.is_alive():  # its owner is gone: what came last is taken in here
                self._drain()

    def heard_hz(self, name: str, since: float) -> float:
        """Messages per second since ``since`` (at most ``window_s`` back), from what the rates thread last took in."""
        when, windows = self._published
        since = max(since, when - self.window_s)
        if when <= since:
            return 0.0
        return sum(1 for t in windows.get(name, ()) if t >= since) / (when - since)

    def observed_hz(self, name: str) -> float:
        """Messages per second over the ``window_s`` seconds up to the rates thread's last wake (at most a second
        ago while it runs; its stop when stopped); safe from any thread, as it changes nothing."""
        when, windows = self._published
        cutoff = when - self.window_s
        return sum(1 for t in windows.get(name, ()) if t >= cutoff) / self.window_s

    # ------------------------------------------------------------------------------------------- internals
    def _on_message(self, msg: mav2.MAVLink_message) -> None:
        """On the receive thread: answer a waiting command, or note when a wanted message came (nothing more)."""
        mtype = msg.get_type()
        if self.link.autopilot is None or (msg.get_srcSystem(), msg.get_srcComponent()) != self.link.autopilot:
            return  # only the autopilot's: another peer's (or, with a key, an unsigned) COMMAND_ACK is no answer
        if mtype == "COMMAND_ACK":
            if msg.target_system in (0, self.link.system_id) and msg.target_component in (0, self.link.component_id):
                with self._ack_cv:
                    self._last_ack = (msg.command, msg.result)
                    self._ack_serial += 1
                    self._ack_cv.notify_all()
            return
        self._inbox.put((mtype, self.clock()))

    def _on_autopilot(self, alive: bool) -> None:
        if alive:  # found, or back after a loss (maybe a reboot that reset every rate): ask for everything
            self._inbox.put(_RESET)
            self._wake.set()

    def _drain(self) -> None:
        """Take in what the inbox holds, trim the windows and publish them (the rates thread's own work)."""
        while True:
            try:
                item = self._inbox.get_nowait()
            except queue.Empty:
                break
            if item is _RESET:
                self._listen_from = self.clock()
                self._asked_at.clear()
                self._backoff.clear()
                self._check_at.clear()
                self._interval_supported = True
                continue
            mtype, t = item
            q = self._arrivals[mtype]
            q.append(t)
            if len(q) > 4 * self.wanted[mtype] * self.window_s + 16:
                q.popleft()
            if mtype not in self._arrived:
                self._arrived.add(mtype)
                if mtype in self.missing:
                    self.missing.discard(mtype)
                    log.info("rates: %s arrives now", mtype)
        now = self.clock()
        cutoff = now - self.window_s
        for q in self._arrivals.values():
            while q and q[0] < cutoff:
                q.popleft()
        self._published = (now, {name: tuple(q) for name, q in self._arrivals.items()})

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self._until_next_check())
            self._wake.clear()
            if self._stop.is_set():
                break
            self._drain()
            if not self.link.autopilot_alive or self.link.autopilot is None:
                continue
            now = self.clock()
            if self._listen_from is not None and now < self._listen_from + self.listen_s:
                continue  # still listening to what arrives unasked
            for name, hz in self.wanted.items():
                if self._stop.is_set() or not self.link.autopilot_alive:
                    break
                self._drain()  # a pass may wait for several acks: judge each rate on what came until now
                asked = self._asked_at.get(name)
                if asked is None and self._listen_from is not None and self._as_found(name, hz):
                    continue
                if asked is not None and (now < self._check_at.get(name, 0.0)
                                          or not self._falls_short(name, hz, asked, now)):
                    continue
                self._request(name, hz)
                self._asked_at[name] = self.clock()
                self._check_at[name] = self._asked_at[name] + max(self.grace_s, self._backoff.get(name, 0.0))
                self._check_missing(name)

    def _falls_short(self, name: str, hz: float, asked: float, now: float) -> bool:
        """At its check: whether ``name`` must be asked for (again), else when it is next looked at. One asked for
        needs half the wanted rate (an autopilot rounds intervals, and a busy one sends less), and is asked again
        less and less often. One left as found needs LEAVE_SHARE of it since it was found: the listen may have been
        too short to judge it (one 3.2 Hz message in a 0.2 s listen reads as 4.7 Hz), or whoever raised the rate
        has lowered it again; either way it is asked for now."""
        found = self.method.get(name) == "as_found"
        rate = self.heard_hz(name, asked) if found else self.observed_hz(name)
        if rate >= (LEAVE_SHARE if found else 0.5) * hz:
            self._check_at[name] = now + self.grace_s
            return False
        if found:
            log.info("rates: %s, left as found, arrives at %.1f Hz (wanted %.1f Hz): asking for it", name, rate, hz)
        else:
            self._backoff[name] = min(2 * max(self._backoff.get(name, self.grace_s), self.grace_s), self.backoff_max_s)
            log.info("rates: %s arrives at %.1f Hz, asked %.1f Hz: asking again", name, rate, hz)
        return True

    def _as_found(self, name: str, hz: float) -> bool:
        """After listening: leave ``name`` alone (checked at each check from now on, ``_falls_short``) if it already
        arrives at LEAVE_SHARE of ``hz`` or more, whoever set that rate."""
        heard = self.heard_hz(name, self._listen_from)
        if heard < LEAVE_SHARE * hz:
            return False
        now = self.clock()
        log.info("rates: %s already arrives at %.1f Hz (wanted %.1f Hz): not asked for", name, heard, hz)
        self.method[name] = "as_found"
        self._asked_at[name] = now
        self._check_at[name] = now + self.grace_s
        return True

    def _until_next_check(self) -> float:
        """Seconds until the next message is due to be checked, or the listening ends (at most 1 s, so a short
        back-off is kept)."""
        if not self.link.autopilot_alive:
            return 1.0  # nothing to ask a lost autopilot; finding it again sets _wake
        now = self.clock()
        due = list(self._check_at.values())
        if self._listen_from is not None and self._listen_from + self.listen_s > now:
            due.append(self._listen_from + self.listen_s)
        return max(0.01, min([1.0, *(t - now for t in due)]))

    def _check_missing(self, name: str) -> None:
        if name in self._arrived or name in self.missing or self.requests[name] < self.missing_after:
            return
        self.missing.add(name)
        log.log(logging.INFO if self.on_missing is not None else logging.WARNING,  # the owner says what it means
                "rates: %s never arrived after %d requests; asking again less and less often (up to every %.0f s)",
                name, self.requests[name], self.backoff_max_s)
        if self.on_missing is not None:
            self.on_missing(name)

    def _request(self, name: str, hz: float) -> None:
        self.requests[name] += 1
        target_sys, target_comp = self.link.autopilot or (self.link.system_id, 1)
        if self._interval_supported:
            msg_id = getattr(mav2, f"MAVLINK_MSG_ID_{name}")
            for _attempt in range(self.retries + 1):
                result = self._command(mav2.MAVLink_command_long_message(
                    target_sys, target_comp, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                    float(msg_id), 1e6 / hz, 0, 0, 0, 0, 0))
                if result is not None:
                    break
            if result is not None:
                self.acks[name] = result
            if result == mav2.MAV_RESULT_ACCEPTED:
                self.method[name] = "interval"
                return
            if result in (mav2.MAV_RESULT_UNSUPPORTED, None):
                self._interval_supported = False
                log.info("rates: SET_MESSAGE_INTERVAL %s; using REQUEST_DATA_STREAM",
                         "unsupported" if result is not None else "not answered")
            else:
                log.warning("rates: autopilot refused %s at %.1f Hz (result %d); trying REQUEST_DATA_STREAM",
                            name, hz, result)
        stream = STREAM_OF.get(name)
        if stream is None:
            log.warning("rates: no data stream carries %s; leaving its rate to the autopilot", name)
            return
        rate = max(1, min(65535, math.ceil(hz)))
        self.link.send(mav2.MAVLink_request_data_stream_message(target_sys, target_comp, stream, rate, 1))
        self.method[name] = "data_stream"

    def _command(self, msg: mav2.MAVLink_message) -> int | None:
        """Send a COMMAND_LONG and wait for its ACK; the MAV_RESULT, or None after ``ack_timeout_s``."""
        with self._ack_cv:
            serial = self._ack_serial
        if not self.link.send(msg):
            self._stop.wait(self.ack_timeout_s)
            return None
        deadline = time.monotonic() + self.ack_timeout_s
        with self._ack_cv:
            while not self._stop.is_set():
                if self._ack_serial != serial and self._last_ack is not None and self._last_ack[0] == msg.command:
                    return self._last_ack[1]
                serial = self._ack_serial
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._ack_cv.wait(left)
        return None
