"""Replay a recorded telemetry log (.tlog) onto a MAVLink connection, keeping its timing.

A tlog (QGroundControl, MAVProxy) is a sequence of records: an 8-byte big-endian timestamp in microseconds since
the epoch, then one MAVLink packet (v1 or v2). Each packet is checked (CRC, known message) and sent unchanged, so
the receiver sees the recorded system/component ids and sequence numbers, at the recorded pace divided by
``speed``. Corrupt records are skipped and counted; after one the reader scans forward to the next record that
looks right (a plausible timestamp followed by a packet whose CRC checks out). The log is read in chunks as it
is replayed (a record never spans more than ~300 bytes, so a window of one chunk is enough): a 2 GB log replays
in the memory of one chunk.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.errors import UsageError
from vehicle.errors import UserError as MerlionError
from vehicle.link.connection import MavLink

log = logging.getLogger(__name__)

_MAX_STEP_US = 24 * 3600 * 1_000_000  # a next record more than a day away is not a timestamp
_MAX_BACK_US = 3600 * 1_000_000
_CHUNK = 256 << 10
_LOOKAHEAD = 1024  # > 8-byte timestamp + the longest signed MAVLink 2 packet (280) + the next record's header


@dataclass(frozen=True)
class TlogRecord:
    t_us: int
    packet: bytes
    src: tuple[int, int]
    msg_type: str


@dataclass
class TlogStats:
    records: int = 0
    bad_crc: int = 0
    """Records whose packet failed its CRC (or could not be decoded): skipped."""
    resync_bytes: int = 0
    """Bytes skipped while looking for the next good record after a corrupt one."""
    unknown: int = 0
    """Packets of messages this dialect does not know: sent on unchecked."""


def _packet_length(data: bytes, at: int) -> int | None:
    """Length of the MAVLink packet starting at ``at`` (from its header), or None when it is not one."""
    if at + 3 > len(data):
        return None
    magic = data[at]
    if magic == mav2.PROTOCOL_MARKER_V2:
        signed = data[at + 2] & mav2.MAVLINK_IFLAG_SIGNED
        return 12 + data[at + 1] + (mav2.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0)
    if magic == mav2.PROTOCOL_MARKER_V1:
        return 8 + data[at + 1]
    return None


def read_tlog(path: str | Path, stats: TlogStats | None = None) -> Iterator[TlogRecord]:
    """The good records of a tlog in file order; bad ones are counted in ``stats``."""
    p = Path(path)
    try:
        f = p.open("rb")
    except FileNotFoundError:
        raise UsageError(f"{p}: no such telemetry log") from None
    except OSError as err:
        raise MerlionError(f"{p}: cannot read ({err.strerror})") from None
    with f:
        yield from _records(p, f, stats if stats is not None else TlogStats())


def _records(p: Path, f: BinaryIO, stats: TlogStats) -> Iterator[TlogRecord]:
    """The record scanner over a sliding window ``data`` of the file; ``base`` is the file offset of data[0]."""
    parser = mav2.MAVLink(None)
    data, base, eof = bytearray(), 0, False
    pos, last_t, found_any = 0, None, False
    in_resync = False
    while True:
        if not eof and len(data) - pos < _LOOKAHEAD:
            try:
                chunk = f.read(_CHUNK)
            except OSError as err:
                raise MerlionError(f"{p}: cannot read ({err.strerror})") from None
            eof = not chunk
            base += pos
            del data[:pos]
            data += chunk
            pos = 0
        if pos + 8 >= len(data):
            break
        t_us = struct.unpack_from(">Q", data, pos)[0]
        length = _packet_length(data, pos + 8)
        plausible = length is not None and pos + 8 + length <= len(data) and (
            last_t is None or -_MAX_BACK_US < t_us - last_t < _MAX_STEP_US)
        record = None
        if plausible:
            packet = bytes(data[pos + 8: pos + 8 + length])
            try:
                msg = parser.decode(bytearray(packet))
                record = TlogRecord(t_us, packet, (msg.get_srcSystem(), msg.get_srcComponent()), msg.get_type())
            except mav2.MAVError as err:
                if "unknown MAVLink message ID" in str(err):
                    stats.unknown += 1
                    head = 5 if packet[0] == mav2.PROTOCOL_MARKER_V2 else 3
                    record = TlogRecord(t_us, packet, (packet[head], packet[head + 1]), "UNKNOWN")
                elif not in_resync:
                    stats.bad_crc += 1
                    log.debug("%s: bad record at byte %d: %s", p, base + pos, err)
            except Exception as err:  # a struct error on a mangled payload is a bad record, not a crash
                if not in_resync:
                    stats.bad_crc += 1
                    log.debug("%s: bad record at byte %d: %s", p, base + pos, err)
        if record is None:
            if not found_any and base + pos > 64 * 1024:
                break
            if not in_resync and plausible:
                # the length byte may be fine and only the payload damaged: try the next record first
                nxt = pos + 8 + length
                if _packet_length(data, nxt + 8) is not None:
                    pos = nxt
                    continue
            in_resync = True
            stats.resync_bytes += 1
            pos += 1
            continue
        in_resync = False
        found_any = True
        last_t = t_us
        stats.records += 1
        yield record
        pos += 8 + len(record.packet)
    if not found_any:
        raise MerlionError(f"{p}: not a MAVLink telemetry log (.tlog): no valid record found")


@dataclass
class ReplayStats:
    sent: int = 0
    bytes: int = 0
    unsent: int = 0
    """Records not written because the connection had no peer yet (a UDP server nobody has spoken to)."""
    filtered: int = 0
    log_seconds: float = 0.0
    wall_seconds: float = 0.0


class TlogReplay:
    """Send a tlog's packets onto ``link`` at ``speed`` times the recorded pace; ``stop()`` from any thread."""

    def __init__(
        self,
        path: str | Path,
        link: MavLink,
        *,
        speed: float = 1.0,
        start_s: float = 0.0,
        duration_s: float | None = None,
        include_gcs: bool = False,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], bool] | None = None,
    ) -> None:
        if speed <= 0:
            raise MerlionError(f"replay speed must be > 0, got {speed}")
        self.path = Path(path)
        self.link = link
        self.speed = speed
        self.start_s = start_s
        self.duration_s = duration_s
        self.include_gcs = include_gcs
        self.clock = clock
        self.log_stats = TlogStats()
        self.stats = ReplayStats()
        self._stop = threading.Event()
        self._wait = wait or self._stop.wait
        """``wait(seconds)`` sleeps and says whether to stop; a test gives a virtual clock's."""

    def stop(self) -> None:
        self._stop.set()

    def run(self, progress: Callable[[ReplayStats], None] | None = None, progress_every_s: float = 10.0) -> ReplayStats:
        """Replay to the end (or ``duration_s``); returns what was sent. ``progress`` is called now and then."""
        first_t = None
        wall0 = self.clock()
        next_progress = progress_every_s
        for rec in read_tlog(self.path, self.log_stats):
            if self._stop.is_set():
                break
            if first_t is None:
                first_t = rec.t_us
            log_s = (rec.t_us - first_t) / 1e6
            if log_s < self.start_s:
                continue
            if self.duration_s is not None and log_s > self.start_s + self.duration_s:
                break
            if not self.include_gcs and rec.src[0] == 255:
                self.stats.filtered += 1
                continue
            due = wall0 + (log_s - self.start_s) / self.speed
            wait = due - self.clock()
            if wait > 0.001 and self._wait(wait):
                break
            if self._stop.is_set():
                break
            written = self.link.send_raw(rec.packet)
            if written:
                self.stats.sent += 1
                self.stats.bytes += written
            else:
                self.stats.unsent += 1
            self.stats.log_seconds = log_s - self.start_s
            self.stats.wall_seconds = self.clock() - wall0
            if progress is not None and self.stats.log_seconds >= next_progress:
                next_progress += progress_every_s
                progress(self.stats)
        self.stats.wall_seconds = self.clock() - wall0
        return self.stats
