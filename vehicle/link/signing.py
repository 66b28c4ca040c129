"""MAVLink 2 message signing for one link: the key, signing what we send, and the gate on what we act on.

With a key, every packet the link sends is signed (pymavlink signs while packing) with a timestamp that never
goes back, across restarts too: timestamps are *reserved* a minute ahead in a small file (fsync + rename) before
they are used, so even a crash cannot hand a timestamp out twice. On receipt, a message that changes state
(``is_state_changing``) is let through only with a valid signature and a timestamp newer than the last one seen
on its (link id, system, component) stream; unsigned or badly signed ones are dropped, counted per source and
reported once per source as a STATUSTEXT warning. The streams' last timestamps live in the same file as our own:
written before a signed state-changing message is acted on (and with each reservation), read back at start, so a
recording replayed after a restart (even after a SIGKILL) is still a replay. Reads (heartbeats, telemetry, parameter and FTP reads) follow
ArduPilot's rule: accepted unsigned unless ``accept_unsigned_reads`` is off.

The check runs here rather than in pymavlink's parser because the link replaces its parser after a truncated
packet or a reconnect (which would forget the stream timestamps and reopen replays), and because pymavlink
records a stream's timestamp before it checks the signature (a forged packet could then block a real sender).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vehicle.errors import UsageError
from vehicle.link.autopilot_signing import (
    NEEDS_A_KEY,
    OTHER_KEY,
    SIGNS_WITH_OUR_KEY,
    UNKNOWN,
    UNSIGNED,
    AutopilotSigning,
)
from vehicle.link.autopilot_watch import is_autopilot_heartbeat
from vehicle.link.refusal_log import RefusalLog
from vehicle.link.warning_bucket import WarningBucket
from vehicle.protocol.ftp import Op
from vehicle.settings import MavlinkConfig

log = logging.getLogger(__name__)

KEY_BYTES = 32
EPOCH_2015 = 1420070400
"""Signing timestamps count 10 us units since 2015-01-01 00:00 UTC."""
UNITS_PER_S = 100_000
NEW_STREAM_WINDOW = 60 * UNITS_PER_S
"""A stream never seen before is accepted only if its timestamp is at most a minute behind ours (the spec's rule)."""
RESERVE_AHEAD = 60 * UNITS_PER_S
MAX_SOURCES = 256
OTHER_SOURCES = (0, 0)
"""Refusals from sources beyond the first ``MAX_SOURCES`` are counted together under this key."""
_SIGNED_FLAG = mavlink2.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN

STATE_CHANGING_TYPES = frozenset({
    "PARAM_SET", "PARAM_EXT_SET", "PARAM_MAP_RC", "COMMAND_LONG", "COMMAND_INT", "COMMAND_CANCEL", "SETUP_SIGNING",
    "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_COUNT", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
    "MISSION_WRITE_PARTIAL_LIST", "RC_CHANNELS_OVERRIDE", "MANUAL_CONTROL", "LOG_ERASE", "FENCE_POINT",
    "RALLY_POINT", "GPS_INJECT_DATA", "GPS_RTCM_DATA", "SERIAL_CONTROL", "DIGICAM_CONTROL", "DIGICAM_CONFIGURE",
    "MOUNT_CONTROL", "MOUNT_CONFIGURE", "PLAY_TUNE", "PLAY_TUNE_V2", "LED_CONTROL", "GIMBAL_MANAGER_SET_ATTITUDE",
})
"""Messages that ask the receiver to change something (plus every ``SET_*`` message and FTP writes)."""
FTP_WRITE_OPCODES = frozenset({Op.CREATE_FILE, Op.WRITE_FILE, Op.REMOVE_FILE, Op.CREATE_DIRECTORY,
                               Op.REMOVE_DIRECTORY, Op.OPEN_FILE_WO, Op.TRUNCATE_FILE, Op.RENAME})
"""FTP opcodes that change files. Ending sessions (TerminateSession, ResetSessions) is not among them: who may end
which session is the FTP server's rule (``SessionTable``: an unsigned request ends only unsigned sessions of its own
ids, and with a key those are read sessions, since opening one for writing needs the key)."""


def now_timestamp(wall_clock: Callable[[], float] = time.time) -> int:
    """The signing timestamp of this instant (0 on a clock still set before 2015, as after a boot without RTC)."""
    return max(0, int((wall_clock() - EPOCH_2015) * UNITS_PER_S))


def key_from_bytes(data: bytes) -> bytes:
    """32 raw bytes are the key; anything else is a passphrase, hashed with SHA-256 as MAVProxy's ``signing
    setup`` does (a 32-character text line counts as a passphrase: raw keys are binary)."""
    if len(data) == KEY_BYTES and not _is_text(data):
        return bytes(data)
    passphrase = data.decode("utf-8", errors="strict").strip()
    if not passphrase:
        raise ValueError("empty passphrase")
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def _is_text(data: bytes) -> bool:
    try:
        return data.decode("ascii").isprintable()
    except UnicodeDecodeError:
        return False


def load_key(path: str | Path) -> bytes:
    """The key in ``path`` (32 raw bytes or a passphrase); a missing or empty file is a one-line error."""
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise UsageError(f"mavlink.signing_key_file {path}: cannot read ({err.strerror})") from None
    try:
        return key_from_bytes(data)
    except (ValueError, UnicodeDecodeError):
        raise UsageError(f"mavlink.signing_key_file {path}: expected 32 raw bytes or a passphrase") from None


def default_timestamp_file(key_file: str | Path, component_id: int) -> Path:
    """One timestamp file per component id beside the key: timestamps must rise per (system, component) stream,
    so the companion, ``merlion telemetry`` and ``merlion doctor`` (all component 100, one after the other)
    share a counter, while the simulator (1) and the surface tool (190) keep their own."""
    key_path = Path(key_file)
    return key_path.with_name(f"{key_path.name}.comp{component_id}.timestamp")


def is_state_changing(msg: mavlink2.MAVLink_message) -> bool:
    """True for messages that ask the receiver to change something: parameter writes, commands, FTP writes."""
    mtype = msg.get_type()
    if mtype == "FILE_TRANSFER_PROTOCOL":
        payload = bytes(msg.payload)
        return len(payload) > 3 and payload[3] in FTP_WRITE_OPCODES
    return mtype in STATE_CHANGING_TYPES or mtype.startswith("SET_")


def _addressed_to(msg: mavlink2.MAVLink_message, me: tuple[int, int]) -> bool:
    """Whether ``msg`` targets ``me`` (a broadcast or a message without target fields does). MANUAL_CONTROL names
    its system in ``target`` (and no component: only a component that acts on it, the autopilot, reports it)."""
    system = getattr(msg, "target_system", getattr(msg, "target", 0))
    component = getattr(msg, "target_component", 0)
    return system in (0, me[0]) and component in (0, me[1])


def _carries_signature(msg: mavlink2.MAVLink_message) -> bool:
    buf = bytes(msg.get_msgbuf())
    return len(buf) > 10 + _SIGNATURE_LEN and buf[0] == mavlink2.PROTOCOL_MARKER_V2 and bool(buf[2] & _SIGNED_FLAG)


AUTOPILOT_UNKNOWN = UNKNOWN
AUTOPILOT_SIGNS_WITH_OUR_KEY = SIGNS_WITH_OUR_KEY
AUTOPILOT_UNSIGNED = UNSIGNED
AUTOPILOT_NEEDS_A_KEY = NEEDS_A_KEY
AUTOPILOT_OTHER_KEY = OTHER_KEY
_HOW_SIGNED = {None: SIGNS_WITH_OUR_KEY, "unsigned": UNSIGNED, "bad signature": OTHER_KEY}
"""How a message from the autopilot was signed, by what ``_verify`` said (a replayed or stale one says nothing)."""


Stream = tuple[int, int, int]
"""(link id, system, component) of a signed sender."""
MAX_SAVED_STREAMS = 1024


class TimestampFile:
    """The highest signing timestamp this link may have used, and the last timestamp accepted from each signed
    stream, written with fsync + rename (never half a file).

    The first line is our own reservation (the whole file, as older versions wrote it); each further line is
    ``stream LINK SYSTEM COMPONENT TIMESTAMP``, so a signed message recorded before a restart is still a replay
    after it."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def _lines(self) -> list[str]:
        try:
            return self.path.read_text().splitlines()
        except FileNotFoundError:
            return []
        except OSError as err:
            log.warning("signing timestamp file %s unreadable (%s); starting from the clock", self.path, err)
            return []

    def load(self) -> int:
        lines = self._lines()
        try:
            return int(lines[0].strip() or 0) if lines else 0
        except ValueError as err:
            log.warning("signing timestamp file %s unreadable (%s); starting from the clock", self.path, err)
            return 0

    def load_streams(self) -> dict[Stream, int]:
        streams: dict[Stream, int] = {}
        for line in self._lines()[1:]:
            parts = line.split()
            if len(parts) == 5 and parts[0] == "stream" and all(p.isdigit() for p in parts[1:]):
                link_id, system, component, stamp = (int(p) for p in parts[1:])
                streams[(link_id, system, component)] = stamp
        return streams

    def save(self, value: int, streams: dict[Stream, int] | None = None) -> None:
        text = f"{value}\n" + "".join(f"stream {k[0]} {k[1]} {k[2]} {v}\n"
                                      for k, v in list((streams or {}).items())[-MAX_SAVED_STREAMS:])
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        try:
            dir_fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(dir_fd)
            finally:
                os.close(dir_fd)
        except OSError:  # some filesystems cannot fsync a directory; the file itself is on disk
            pass


class LinkSigning:
    """Signing state of one link; ``prepare`` runs under the link's send lock, ``admit`` on its receive thread."""

    def __init__(
        self,
        key: bytes | None = None,
        *,
        name: str = "link",
        timestamp_file: Path | None = None,
        accept_unsigned_reads: bool = True,
        link_id: int = 0,
        wall_clock: Callable[[], float] = time.time,
        unsigned_autopilot: bool = False,
    ) -> None:
        self.name = name
        self.accept_unsigned_reads = accept_unsigned_reads
        self.unsigned_autopilot = unsigned_autopilot
        """With a key, still take an autopilot that does not sign (``mavlink.unsigned_autopilot``)."""
        self.trust_unsigned = False
        """ArduPilot's channel 0 (SERIAL0, USB): with a key, still act on every unsigned or badly signed packet (tests
        set it on the simulator's link to make it that port); never set on the companion."""
        self.announce_refusals = True
        """Say on the wire (one STATUSTEXT per source) that a refused message was ignored; an ArduSub autopilot
        never does: it drops what it refuses silently (the simulator turns this off)."""
        self.link_id = link_id
        self.wall_clock = wall_clock
        self._store = TimestampFile(timestamp_file) if timestamp_file is not None else None
        self._key: bytes | None = None
        self._floor = 0
        self._reserved = 0
        self._time_floor = 0
        self._lock = threading.Lock()
        self._save_lock = threading.Lock()
        self._streams: dict[Stream, int] = {}
        self.accepted_signed = 0
        self.accepted_unsigned_reads = 0
        self.dropped_for_others = 0
        self.warnings_withheld = 0
        self._warnings = WarningBucket()
        self.refusal_log = RefusalLog(name, log)
        """The log lines about new refused sources: the first in full, then a count per interval (a flood of
        made-up ids wrote a line each); the link's timer thread flushes it and sets its clock."""
        self.rejected: dict[tuple[int, int], int] = {}
        """Refused state-changing messages by source (system, component)."""
        self.reasons: dict[tuple[int, int], str] = {}
        self.last_signed_from: dict[tuple[int, int], int] = {}
        """Signing timestamp of the last valid signed message from each source (system, component)."""
        self._protected: tuple[int, int] | None = None
        self.claimed: tuple[int, int] | None = None
        """The last source that sent an autopilot heartbeat, signed or not (whom to ask before one is settled)."""
        self.watch = AutopilotSigning(name=name, clock=time.monotonic, window_s=3.0, has_key=lambda: self.enabled,
                                      required=lambda: self.require_signed_autopilot)
        """How the autopilot signs and whether it obeys, for the whole run (the link sets its clock and window)."""
        self.spoofed: dict[tuple[int, int], int] = {}
        """Unsigned (or badly signed) messages claiming to be the autopilot that were not used: with a key, all of
        them (unless ``unsigned_autopilot``), else those after the autopilot was seen signing."""
        if key is not None:
            self.set_key(key)

    @classmethod
    def from_settings(cls, cfg: MavlinkConfig, *, name: str) -> LinkSigning:
        """From the ``mavlink`` settings; no key file: signing off, everything accepted as before."""
        if not cfg.signing_key_file:
            return cls(None, name=name, accept_unsigned_reads=cfg.accept_unsigned_reads)
        stamp = (Path(cfg.signing_timestamp_file) if cfg.signing_timestamp_file
                 else default_timestamp_file(cfg.signing_key_file, cfg.component_id))
        if not stamp.parent.is_dir() or not os.access(stamp.parent, os.W_OK):
            raise UsageError(f"mavlink.signing_timestamp_file {stamp}: folder missing or not writable")
        return cls(load_key(cfg.signing_key_file), name=name, timestamp_file=stamp,
                   accept_unsigned_reads=cfg.accept_unsigned_reads, unsigned_autopilot=cfg.unsigned_autopilot)

    # ------------------------------------------------------------------------------------------------ key
    @property
    def enabled(self) -> bool:
        return self._key is not None

    @property
    def require_signed_autopilot(self) -> bool:
        """With a key, only the autopilot's signed messages are used, from the very first packet: an unsigned
        heartbeat never settles who the autopilot is nor keeps it alive, and once it is settled no unsigned message
        under its ids reaches a subscriber (MAVLink 1 framing cannot be signed at all). Before that, unsigned reads
        from any ids pass (its ids are not known yet): the autopilot's subscribers (telemetry, the rate keeper) take
        nothing while ``MavLink.autopilot`` is None."""
        return self._key is not None and not self.unsigned_autopilot

    @property
    def autopilot(self) -> str:
        """How the autopilot signs, as far as its recent messages show (one of the AUTOPILOT_* values)."""
        return self.watch.signs

    def set_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Use ``key`` from now on (None or all zeros: signing off), as SETUP_SIGNING does on an autopilot."""
        with self._lock:
            if key is None or not any(key):
                self._key = None
                return
            if len(key) != KEY_BYTES:
                raise ValueError(f"signing key must be {KEY_BYTES} bytes, got {len(key)}")
            self._key = bytes(key)
            stored = self._store.load() if self._store else 0
            self._floor = max(self._floor, initial_timestamp, stored)
            self._reserved = self._floor
            # what we know of the time without a clock (no RTC at boot): the last reservation was made at most
            # RESERVE_AHEAD before it, and a ground station's SETUP_SIGNING carries its own time
            self._time_floor = max(self._time_floor, initial_timestamp, stored - RESERVE_AHEAD)
            self._streams.clear()
            if self._store is not None:  # what we accepted before a restart stays accepted only once
                self._streams.update(self._store.load_streams())

    # ------------------------------------------------------------------------------------------------ send
    def prepare(self, tx: mavlink2.MAVLink) -> None:
        """Make ``tx`` sign the next packet with a fresh timestamp (or not sign, without a key)."""
        key = self._key
        sig = tx.signing
        if key is None:
            sig.sign_outgoing = False
            sig.secret_key = None
            return
        sig.secret_key = key
        sig.sign_outgoing = True
        sig.link_id = self.link_id
        stamp = max(sig.timestamp, self._floor, now_timestamp(self.wall_clock))
        if self._store is not None and stamp >= self._reserved - RESERVE_AHEAD // 2:
            self._reserve(stamp + RESERVE_AHEAD)
        sig.timestamp = stamp
        self._floor = stamp

    def _reserve(self, value: int) -> None:
        """Write the reservation before any timestamp under it goes out (one small fsync every ~30 s)."""
        self._persist(value)
        self._reserved = value  # also after a failure: do not retry on every packet

    def _persist(self, reserved: int | None = None) -> None:
        """Write our reservation and every stream's last accepted timestamp (one file, fsync + rename)."""
        with self._save_lock:
            with self._lock:
                streams = dict(self._streams)
            value = max(self._reserved, reserved or 0)
            try:
                self._store.save(value, streams)
            except OSError as err:  # keep going: the clock still moves on; say so once per failure
                log.warning("%s: cannot persist the signing timestamps to %s: %s", self.name, self._store.path, err)

    # ------------------------------------------------------------------------------------------------ receive
    def admit(self, msg: mavlink2.MAVLink_message, send: Callable[[mavlink2.MAVLink_message], int],
              me: tuple[int, int] | None = None,
              refused: Callable[[mavlink2.MAVLink_message, str], None] | None = None, handled: bool = True) -> bool:
        """True when ``msg`` may be acted on; a refused one addressed to ``me`` (system, component) that this
        component ``handled`` (some part of it asked for that type) is counted, handed to ``refused(msg, reason)``
        (which may answer it) and, once per source, reported (one meant for another component on a shared link,
        or of a type nobody here acts on, is just dropped)."""
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        claims = source == self._protected or (self._protected is None and is_autopilot_heartbeat(msg))
        if claims and msg.get_type() == "HEARTBEAT":
            self.claimed = source
        if self._key is None:
            if claims:
                self.watch.saw(NEEDS_A_KEY if _carries_signature(msg) else UNSIGNED)
            return True
        reason = self._verify(msg)
        if claims and reason in _HOW_SIGNED:
            self.watch.saw(_HOW_SIGNED[reason])
        if reason is None:
            self.accepted_signed += 1
            return True
        if self.trust_unsigned:
            self.accepted_unsigned_reads += 1
            return True
        if claims and (self.require_signed_autopilot or source in self.last_signed_from):
            self._count_spoof(source, reason, msg.get_type())
            return False
        if self.accept_unsigned_reads and not is_state_changing(msg):
            self.accepted_unsigned_reads += 1
            return True
        if not handled or (me is not None and not _addressed_to(msg, me)):
            self.dropped_for_others += 1
            return False
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if source not in self.rejected and len(self.rejected) >= MAX_SOURCES:
            source = OTHER_SOURCES  # spoofed ids by the thousand must not grow the table (or the warnings)
        count = self.rejected.get(source, 0) + 1
        self.rejected[source] = count
        if refused is not None:
            refused(msg, reason)
        if count == 1:
            self.reasons[source] = reason
            name = "FTP write" if msg.get_type() == "FILE_TRANSFER_PROTOCOL" else msg.get_type()
            text = f"{reason} {name} from {source[0]}/{source[1]} ignored"  # fits STATUSTEXT's 50 characters
            self.refusal_log.refused(text)
            if self.announce_refusals and self._warnings.take():
                send(mavlink2.MAVLink_statustext_message(mavlink2.MAV_SEVERITY_WARNING, text[:50].encode()))
            elif self.announce_refusals:
                self.warnings_withheld += 1
        return False

    @property
    def mismatch(self) -> bool:
        """The autopilot signs with a key we lack and does not answer us: it ignores everything this link sends."""
        return self.watch.verdict.mismatch

    def protect(self, source: tuple[int, int]) -> None:
        """``source`` (the autopilot) signs everything once it has a key, as ArduPilot does: with our key (or, with
        ``unsigned_autopilot``, after one valid signed message from it), nothing unsigned or badly signed that
        claims to be it is acted on (a spoofed HEARTBEAT would move the vehicle's identity or keep a lost autopilot
        "alive", a spoofed ATTITUDE or GLOBAL_POSITION_INT would tag frames)."""
        self._protected = source

    def _count_spoof(self, source: tuple[int, int], reason: str, mtype: str) -> None:
        count = self.spoofed.get(source, 0) + 1
        self.spoofed[source] = count
        if count == 1:
            log.warning("%s: %s %s claiming to be the autopilot %d/%d ignored (with a key only its signed messages "
                        "count); further ones are only counted", self.name, reason, mtype, *source)

    def _verify(self, msg: mavlink2.MAVLink_message) -> str | None:
        """None when ``msg`` carries a valid signature with a fresh timestamp; else why not."""
        buf = bytes(msg.get_msgbuf())
        if len(buf) < 10 + _SIGNATURE_LEN or buf[0] != mavlink2.PROTOCOL_MARKER_V2 or not buf[2] & _SIGNED_FLAG:
            return "unsigned"
        expected = hashlib.sha256(self._key + buf[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, buf[-6:]):
            return "bad signature"
        link_id = buf[-13]
        stamp = int.from_bytes(buf[-12:-6], "little")
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        stream = (link_id, *source)
        with self._lock:
            last = self._streams.get(stream)
            if last is not None and stamp <= last:
                return "replayed"
            if last is None and stamp + NEW_STREAM_WINDOW < max(self._time_floor, now_timestamp(self.wall_clock)):
                return "stale signed"
            self._streams[stream] = stamp
        if self._store is not None and is_state_changing(msg):
            # on disk before it is acted on: a SIGKILL right after cannot reopen this timestamp to a replay. One
            # fsync on the receive loop per accepted signed write (10.6 ms measured on the dev machine's disk): the
            # operator's PARAM_SETs, commands and FTP writes only; reads and telemetry never wait for it
            self._persist()
        self.last_signed_from[source] = stamp
        msg._signed = True
        msg._link_id = link_id
        return None

    def stats(self) -> dict[str, object]:
        """Counters for status reports, ``merlion doctor`` and logs."""
        return {
            "enabled": self.enabled, "accepted_signed": self.accepted_signed,
            "accepted_unsigned_reads": self.accepted_unsigned_reads, "dropped_for_others": self.dropped_for_others,
            "warnings_withheld": self.warnings_withheld,
            "rejected": sum(self.rejected.values()),
            "rejected_by_source": {f"{s}/{c}": n for (s, c), n in sorted(self.rejected.items())},
            "spoofed_autopilot": sum(self.spoofed.values()), "autopilot": self.autopilot,
            "autopilot_obeys": self.watch.obeys, "mismatch": self.mismatch,
            "autopilot_changes": [f"{v.signs}, {'obeys' if v.obeys else 'ignores'} us" for v in self.watch.changes],
            "autopilot_changes_withheld": self.watch.withheld,
        }
