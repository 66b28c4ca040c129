"""How the autopilot signs and whether it obeys this companion, watched for the whole run.

A pilot can run MAVProxy's ``signing setup`` mid-dive, and what signing costs the companion depends on the port:
ArduPilot with a key drops every unsigned packet, except on its channel 0 (SERIAL0, USB), which it trusts
(``accept_unsigned_callback`` in ArduPilot's libraries/GCS_MAVLink/GCS_Signing.cpp). So the verdict has two halves:
how the autopilot's messages are signed (the freshest evidence in the last ``window_s``: a valid signature beats a
bad one, a bad one beats none, since a stranger can send unsigned messages under its ids but not sign them), and
whether it answers this companion's commands (a COMMAND_ACK after our rate requests, or after a probe,
MAV_CMD_GET_MESSAGE_INTERVAL, sent whenever the signing changes and at first sight of a key we lack; a first
"signs with our key" or "does not sign" is presumed obeyed until three requests go unanswered). Each new verdict is said once: a log line and, through ``on_change`` callbacks, a STATUSTEXT.

The receive thread records what it saw (``saw``, ``answered``), the writer notes commands (``asked``), and the link's
timer thread alone judges (``judge``), so the callbacks run on one thread, in order.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vehicle.link.warning_bucket import WarningBucket

log = logging.getLogger(__name__)

UNKNOWN = "unknown"
SIGNS_WITH_OUR_KEY = "signs with our key"
UNSIGNED = "does not sign"
NEEDS_A_KEY = "signs, and this companion has no key"
OTHER_KEY = "signs with another key"
MISMATCHED = frozenset({NEEDS_A_KEY, OTHER_KEY})
"""Signed with a key we cannot sign with: on SERIAL1 and up it drops whatever we send."""
_STRENGTH = (SIGNS_WITH_OUR_KEY, OTHER_KEY, NEEDS_A_KEY, UNSIGNED)
"""Which evidence wins when several kinds arrived in the window (a spoofer adds unsigned messages, never signed ones)."""

_PRESUMED = frozenset({SIGNS_WITH_OUR_KEY, UNSIGNED})
"""A first verdict that needs no probe: such an autopilot takes what we send (our key, or no key at all) until our
requests go unanswered."""
_COMMANDS = frozenset({"COMMAND_LONG", "COMMAND_INT"})
UNANSWERED_ASKS = 3
"""Commands to the autopilot left unanswered, the oldest ``ASK_WAIT_S`` ago, before it counts as not obeying."""
ASK_WAIT_S = 2.0
PROBE_EVERY_S = 1.0
PROBES = 3
CHANGES_SAID = 4
"""Changes of verdict said (log line and STATUSTEXT) at once; then one more each ``CHANGE_REFILL_S``. A stranger
can forge every kind of evidence but a signature with our key (an unsigned message, or one whose signature flag is
set and its signature garbage, under the autopilot's ids): alternating them it flipped the verdict, and a
STATUSTEXT went out, every few seconds for as long as it liked. A pilot's signing change is one or two."""
CHANGE_REFILL_S = 60.0


def probe_message(target: tuple[int, int]) -> mavlink2.MAVLink_message:
    """Something harmless to ask the autopilot: the heartbeat's interval (a read, answered with a COMMAND_ACK)."""
    return mavlink2.MAVLink_command_long_message(*target, mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL, 0,
                                                 mavlink2.MAVLINK_MSG_ID_HEARTBEAT, 0, 0, 0, 0, 0, 0)


@dataclass(frozen=True)
class Verdict:
    """What the autopilot does: how it signs and whether it answers us (None: not asked yet)."""

    signs: str
    obeys: bool | None

    @property
    def mismatch(self) -> bool:
        """It signs with a key we lack and does not answer us: nothing we send reaches it (nor, routed, anyone)."""
        return self.signs in MISMATCHED and self.obeys is not True


def describe(v: Verdict, *, has_key: bool, required: bool) -> tuple[str, str, int]:
    """(log line, STATUSTEXT of at most 50 characters, MAV_SEVERITY) for a verdict."""
    sev = mavlink2
    if v.signs == SIGNS_WITH_OUR_KEY:
        if v.obeys is False:
            return ("the autopilot signs with our key but does not answer this companion's signed requests",
                    "Autopilot signs but ignores our requests", sev.MAV_SEVERITY_WARNING)
        return "the autopilot signs with our key", "Autopilot signs with our key", sev.MAV_SEVERITY_INFO
    if v.signs == NEEDS_A_KEY:
        if v.obeys:
            return ("the autopilot signs its messages and still obeys this companion's unsigned requests (ArduPilot "
                    "trusts its channel 0, SERIAL0/USB; on any other port it would ignore them): give the companion "
                    "its passphrase (mavlink.signing_key_file or --signing-key, docs/security.md)",
                    "Autopilot signs; takes our unsigned requests", sev.MAV_SEVERITY_WARNING)
        return ("the autopilot signs its messages and this companion has no signing key: the autopilot ignores "
                "everything the companion sends (heartbeat, STATUSTEXT, rate requests); give it the autopilot's "
                "passphrase (mavlink.signing_key_file or --signing-key, docs/security.md)",
                "Autopilot signs: it ignores us (no key)", sev.MAV_SEVERITY_ERROR)
    if v.signs == OTHER_KEY:
        if v.obeys:
            return ("the autopilot signs with another key than this companion's, yet answers it (SERIAL0/USB); "
                    "use the autopilot's passphrase (docs/security.md)",
                    "Autopilot signs with another key", sev.MAV_SEVERITY_WARNING)
        return ("the autopilot signs with another key than this companion's: it ignores everything the companion "
                "sends; use the autopilot's passphrase (docs/security.md)",
                "Autopilot signs with another key: ignores us", sev.MAV_SEVERITY_ERROR)
    if has_key and required:
        return ("the autopilot's messages arrive unsigned and this companion has a key: its heartbeat and telemetry "
                "are not used (frames are tagged without depth or pose) until it signs; put the passphrase on the "
                "autopilot, or set mavlink.unsigned_autopilot: true for one that cannot sign (docs/security.md)",
                "Autopilot does not sign: telemetry unused", sev.MAV_SEVERITY_ERROR)
    if has_key:
        return ("the autopilot does not sign: it obeys anyone on the link, and anyone can pose as it "
                "(mavlink.unsigned_autopilot is on)", "Autopilot does not sign: it obeys anyone",
                sev.MAV_SEVERITY_WARNING)
    return "the autopilot does not sign", "Autopilot does not sign", sev.MAV_SEVERITY_NOTICE


class AutopilotSigning:
    """The autopilot's signing verdict, judged on one thread from what the receive and send paths recorded."""

    def __init__(self, *, name: str, clock: Callable[[], float], window_s: float,
                 has_key: Callable[[], bool], required: Callable[[], bool]) -> None:
        self.name = name
        self.clock = clock
        self.window_s = window_s
        self._has_key = has_key
        self._required = required
        self._lock = threading.Lock()
        self._seen: dict[str, float] = {}
        self._asks: list[float] = []
        """When each command to the autopilot since its last answer was sent."""
        self._answered = False
        self.signs = UNKNOWN
        self.obeys: bool | None = None
        self.said: Verdict | None = None
        self.changes: list[Verdict] = []
        """Every verdict said, in order (for ``merlion doctor``, status and tests)."""
        self._probes_left = 0
        self._next_probe = 0.0
        self._callbacks: list[Callable[[str, int], None]] = []
        self._changes_said = WarningBucket(CHANGES_SAID, CHANGE_REFILL_S, clock=clock)
        self.withheld = 0
        """Changes of verdict not said (beyond ``CHANGES_SAID``): counted, and the first of them logged."""

    def on_change(self, callback: Callable[[str, int], None]) -> None:
        """``callback(text, severity)`` for each verdict worth a STATUSTEXT (a change, or a first one that is bad)."""
        self._callbacks.append(callback)

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.signs, self.obeys)

    # ------------------------------------------------------------------------------------ receive / send threads
    def saw(self, kind: str) -> None:
        """A message from (or an autopilot heartbeat claiming to be) the autopilot, signed as ``kind``."""
        with self._lock:
            self._seen[kind] = self.clock()

    def answered(self) -> None:
        """A COMMAND_ACK from the autopilot to us: it obeys what we send."""
        with self._lock:
            self._asks.clear()
            self._answered = True

    def outgoing(self, msg: mavlink2.MAVLink_message, autopilot: tuple[int, int] | None) -> None:
        """A message going out (on the writer): a command to the autopilot is due an answer."""
        if msg.get_type() in _COMMANDS and (msg.target_system, msg.target_component) == autopilot:
            self.asked()

    def incoming_ack(self, ack: mavlink2.MAVLink_message, autopilot: tuple[int, int] | None,
                     me: tuple[int, int]) -> None:
        """A COMMAND_ACK received: from the autopilot to us (target 0: an older autopilot that leaves them out)."""
        if ((ack.get_srcSystem(), ack.get_srcComponent()) == autopilot
                and ack.target_system in (0, me[0]) and ack.target_component in (0, me[1])):
            self.answered()

    def asked(self) -> None:
        """A command to the autopilot went out."""
        with self._lock:
            self._asks.append(self.clock())

    def probe(self) -> None:
        """Ask the autopilot again whether it answers us (``merlion doctor`` wants it proven, not presumed): judged
        on the answers to come, not on requests it left unanswered before (under another signing)."""
        with self._lock:
            self._asks.clear()
            self._answered = False
        self.obeys = None
        self._probes_left, self._next_probe = PROBES, self.clock()

    # ------------------------------------------------------------------------------------ the judging thread
    def judge(self, probe: Callable[[], bool]) -> None:
        """Update the verdict; ``probe()`` sends one command to the autopilot (False: no autopilot to ask yet)."""
        now = self.clock()
        with self._lock:
            fresh = [k for k in _STRENGTH if now - self._seen.get(k, -1e18) <= self.window_s]
        if fresh and fresh[0] != self.signs:
            first = self.signs == UNKNOWN
            self.signs = fresh[0]
            if first and self.signs in _PRESUMED:
                self.obeys = True  # until requests go unanswered: no probe on a healthy link
            else:
                self.probe()
        with self._lock:  # after a change: only what was asked since counts
            answered, self._answered = self._answered, False
            unanswered = len(self._asks) >= UNANSWERED_ASKS and now - self._asks[0] >= ASK_WAIT_S
        if answered:
            self.obeys = True
        elif unanswered:
            self.obeys = False
        if self.obeys is None and self._probes_left and now >= self._next_probe and probe():
            self._probes_left -= 1
            self._next_probe = now + PROBE_EVERY_S
        if self.signs != UNKNOWN and self.obeys is not None and self.verdict != self.said:
            self._say(self.verdict)

    def _say(self, v: Verdict) -> None:
        first = self.said is None
        self.said = v
        self.changes.append(v)
        text, status, severity = describe(v, has_key=self._has_key(), required=self._required())
        bad = severity <= mavlink2.MAV_SEVERITY_WARNING
        if not first and not self._changes_said.take():
            self.withheld += 1
            if self.withheld == 1:
                log.warning("%s: the autopilot's signing verdict keeps changing (now: %s); a stranger may be sending "
                            "under its ids: further changes are only counted", self.name, text)
            return
        if first:
            (log.error if severity <= mavlink2.MAV_SEVERITY_ERROR else log.warning if bad else log.info)(
                "%s: %s", self.name, text)
        else:
            log.warning("%s: signing changed: %s", self.name, text)
        if first and not bad:
            return  # the expected state at start-up is no news for the surface
        for callback in list(self._callbacks):
            try:
                callback(status, severity)
            except Exception:
                log.exception("%s: signing callback failed", self.name)
