"""A small MAVLink FTP (FILE_TRANSFER_PROTOCOL, 110) client that reads (and uploads small) files, fed by someone
else's receive loop.

pymavlink's ``mavftp`` reads the connection itself (``recv_match`` in its own loops), which would steal the
captures and thumbnails the surface tool's one receive loop must see; so this client is a message-driven state
machine instead: ``handle`` takes FTP replies, ``tick`` re-asks for what the link lost. One request is in flight
at a time (the companion paces FTP last in its byte budget, so more would only queue duplicates there). Requests
wait in a queue per lane (each requester its own: index pulls, thumbnails, the page's requests), served in turn, a
request from each lane that has one, so a flood of one requester's fetches never starves another's; each lane holds
``MAX_QUEUED`` at most.
Protocol: mavlink.io/en/services/ftp.html.
"""

from __future__ import annotations

import logging
import secrets
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from vehicle.protocol.ftp import MAX_DATA, FtpErr, FtpPacket, Op, crc32_ardupilot

log = logging.getLogger("merlion.surface.ftp")

SendFn = Callable[[int, int, bytes], None]
"""send(target_system, target_component, payload) puts one FILE_TRANSFER_PROTOCOL on the wire."""
DoneFn = Callable[[str, "bytes | None", str], None]
"""done(path, data or None, error text) is called once per fetch."""
crc32_mavftp = crc32_ardupilot
"""The CRC-32 a server answers CalcFileCRC32 with, so a file we hold is checked with one small request."""
MAX_FILE_BYTES = 16 * 1024 * 1024
"""The largest file read: a thumbnail, index.json or a full frame is kilobytes to a few MB. The size comes from
the server's open ACK (a u32): a hostile one announcing 4 GiB made the client allocate two buffers of that size
before it read a byte."""
MAX_QUEUED = 64
"""Requests waiting per lane (requester: the index, the thumbnails, the page). Past it a request is refused at once
(``done`` hears why): a sender making the tool fetch without end grew one queue for the whole run."""


@dataclass
class _Job:
    path: str
    done: DoneFn
    crc_only: bool = False
    """Ask the server for the file's CRC-32 (``done`` gets its 4 bytes, little endian) instead of reading it."""
    known: dict[int, bytes] = field(default_factory=dict)
    """Bytes the caller already has, by offset (what a stalled push delivered): only the rest is read."""
    known_size: int | None = None
    """Size of the file ``known`` came from; the known bytes are used only if the server's file has this size."""
    session: int | None = None
    size: int | None = None
    """From the OpenFileRO ACK; None when the server did not say (then read to EOF)."""
    buf: bytearray = field(default_factory=bytearray)
    have: bytearray = field(default_factory=bytearray)
    """One byte per file byte: 1 where ``buf`` holds data received."""
    error: str = ""
    upload: bytes | None = None
    """Write this file (CreateFile, WriteFile, TerminateSession) instead of reading it; ``done`` gets it back."""
    written: int = 0

    def start(self, size: int | None) -> None:
        self.size = size
        if size is None:
            return
        self.buf, self.have = bytearray(size), bytearray(size)
        if self.known and self.known_size == size:
            for offset, data in self.known.items():
                data = data[: max(0, size - offset)]
                self.buf[offset : offset + len(data)] = data
                self.have[offset : offset + len(data)] = b"\1" * len(data)

    def hole(self) -> tuple[int, int] | None:
        """The first run of missing bytes as (offset, length), or None when the file is complete."""
        start = self.have.find(0)
        if start < 0:
            return None
        stop = self.have.find(1, start)
        return start, (len(self.have) if stop < 0 else stop) - start

    def store(self, offset: int, data: bytes) -> int:
        """Keep ``data`` at ``offset``; returns how many bytes were new."""
        if self.size is None:  # size unknown: only the next bytes in order
            if offset != len(self.buf) or not data:
                return 0
            self.buf.extend(data)
            return len(data)
        data = data[: max(0, self.size - offset)]
        if not data:
            return 0
        new = self.have[offset : offset + len(data)].count(0)
        self.buf[offset : offset + len(data)] = data
        self.have[offset : offset + len(data)] = b"\1" * len(data)
        return new


class FtpClient:
    """Fetches whole files from one MAVLink FTP server, one after another, retransmitting what the link lost.

    A file whose size the server told is read with BurstReadFile (the server streams it at the pace of its own
    byte budget, no round trip per packet); the holes a lossy link leaves are filled with ReadFile (one or two)
    or a new burst from the first hole. The retransmission timeout follows the measured round trip (RFC 6298
    style, Karn's rule, doubling on each timeout), because the companion sends FTP last in its link budget and
    a round trip there can take seconds while thumbnails drain.
    """

    def __init__(self, send: SendFn, target: tuple[int, int], *, own: tuple[int, int] | None = None,
                 clock: Callable[[], float] = time.monotonic, min_timeout_s: float = 0.5,
                 max_timeout_s: float = 3.0, max_tries: int = 10, burst: bool = True,
                 max_file_bytes: int = MAX_FILE_BYTES, session: int | None = None,
                 max_queued: int = MAX_QUEUED) -> None:
        """``session``: the session number this client opens its files with (default: a random one)."""
        self._send = send
        self.max_queued = max_queued
        self.max_file_bytes = max_file_bytes
        self.target = target
        self._own = own
        self._clock = clock
        self._min_timeout, self._max_timeout, self._max_tries = min_timeout_s, max_timeout_s, max_tries
        self._burst = burst
        self._lanes: dict[str, deque[_Job]] = {}
        """Waiting requests by lane, in the order the lanes first asked (a handful of names, fixed by the callers)."""
        self._last_lane: str | None = None
        self._finishing = False
        self.refused = 0
        """Requests refused because their lane held ``max_queued`` already."""
        self._job: _Job | None = None
        self._job_lane = ""
        self._seq = secrets.randbelow(0x10000)
        """Starts anywhere: a server answers a request it has seen from our ids lately (same sequence number, same
        bytes) from its retransmission cache, so a client restarted within that window must not repeat its old
        sequence (a second ``surface-queries`` got the first one's closed session back)."""
        self.session = secrets.randbelow(0x100) if session is None else session & 0xFF
        """The session number asked for at each open (servers grant it, or say which they gave). Every client used
        0: a server keeps sessions per sender ids and an open on a number the same ids hold replaces that session,
        so two tools with the same ids (two ``merlion surface``, or one and ``surface-mark``) cut each other's
        downloads short, and a spoofer needed no guess to replace our session or inject burst data into it."""
        self._request: tuple[int, bytes, int] | None = None  # (opcode, payload, offset) awaiting its reply
        self._sent_at = 0.0
        self._tries = 0
        self._sampled = False
        self._srtt: float | None = None
        self._rttvar = 0.0
        self.started_wall = 0.0
        """Wall clock when the current (or, inside ``done``, the finished) download sent its open request:
        the server built the file after that moment."""
        self.retransmissions = 0
        self.bytes_read = 0
        self.files_done = 0

    # --- public --------------------------------------------------------------------------------------------

    def fetch(self, path: str, done: DoneFn, *, known: dict[int, bytes] | None = None,
              known_size: int | None = None, lane: str = "") -> None:
        """Queue a download of ``path`` (e.g. ``/summary/3.jpg``); ``done`` hears the outcome exactly once.

        ``known`` (offset -> bytes of a file of ``known_size`` bytes, e.g. the packets of a stalled push) are
        not read again when the server's file has that size: on a lossy link that saves most of the transfer.
        ``lane``: the requester, whose requests wait apart and are served in turn with the other lanes'.
        """
        self._enqueue(_Job(path, done, known=dict(known or {}), known_size=known_size), lane)

    def crc(self, path: str, done: Callable[[str, int | None, str], None], *, lane: str = "") -> None:
        """Queue a CalcFileCRC32 of ``path``; ``done(path, crc or None, error)`` (see ``crc32_mavftp``)."""

        def unpack_crc(p: str, data: bytes | None, error: str) -> None:
            done(p, None if data is None else struct.unpack("<I", data)[0], error)

        self._enqueue(_Job(path, unpack_crc, crc_only=True), lane)

    def upload(self, path: str, data: bytes, done: DoneFn, *, lane: str = "") -> None:
        """Queue an upload of ``data`` to ``path`` (e.g. ``/config/marks.json``); ``done(path, data or None,
        error)``: a server that refuses the file (it answers the closing request with a NAK) is an error."""
        self._enqueue(_Job(path, done, upload=bytes(data)), lane)

    def pending(self, lane: str | None = None) -> list[str]:
        """The paths asked for and not done (of ``lane`` only, when given), the one in progress first."""
        paths = [j.path for name, jobs in self._lanes.items() if lane in (None, name) for j in jobs]
        current = self._job is not None and lane in (None, self._job_lane)
        return [self._job.path, *paths] if current else paths

    def _enqueue(self, job: _Job, lane: str) -> None:
        jobs = self._lanes.setdefault(lane, deque())
        if len(jobs) >= self.max_queued:
            self.refused += 1
            job.done(job.path, None, f"refused: {len(jobs)} requests of this kind wait already")
            return
        jobs.append(job)
        if self._job is None and not self._finishing:
            self._next_job()

    @property
    def busy(self) -> bool:
        return self._job is not None

    def handle(self, msg) -> None:
        """Feed a FILE_TRANSFER_PROTOCOL message; replies to others or to stale requests are ignored."""
        if msg.get_type() != "FILE_TRANSFER_PROTOCOL" or self._request is None or self._job is None:
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.target:
            return
        if self._own is not None and (msg.target_system, msg.target_component) not in (self._own, (self._own[0], 0)):
            return
        reply = FtpPacket.unpack(msg.payload)
        opcode, _, offset = self._request
        if reply.opcode not in (Op.ACK, Op.NAK) or reply.req_opcode != opcode:
            return
        if opcode == Op.BURST_READ_FILE:
            if reply.session != self._job.session:
                return
            self._sample()
            self._on_burst(reply)
            return
        if reply.seq != (self._seq + 1) & 0xFFFF:
            return
        self._sample()
        self._request = None
        self._seq = (reply.seq + 1) & 0xFFFF
        self._on_reply(opcode, offset, reply)

    def tick(self) -> None:
        """Call often: re-asks for what is overdue, gives up after ``max_tries`` silent timeouts in a row."""
        if self._request is None or self._job is None:
            return
        if self._clock() - self._sent_at < self._timeout():
            return
        opcode, payload, _ = self._request
        self.retransmissions += 1
        if self._tries >= self._max_tries:
            self._request = None
            if opcode == Op.TERMINATE_SESSION and self._job.upload is None:
                self._complete()  # every byte is in; the server ends an idle session on its own
                return
            what = {Op.OPEN_FILE_RO: "open", Op.TERMINATE_SESSION: "close", Op.CALC_FILE_CRC32: "CRC request",
                    Op.CREATE_FILE: "create", Op.WRITE_FILE: "write"}.get(opcode, "read")
            self._finish(None, f"no answer to {what} after {self._tries} tries")
            return
        if opcode == Op.BURST_READ_FILE:
            tries = self._tries
            self._continue()  # ask again from the first hole (a new burst replaces the server's old one)
            self._tries = tries + 1
            return
        self._transmit(opcode, payload, self._request[2], retry=True)

    # --- protocol ------------------------------------------------------------------------------------------

    def _sample(self) -> None:
        """One round-trip sample per request, and only from a request sent once (Karn's rule)."""
        if self._sampled or self._tries != 1:
            return
        self._sampled = True
        rtt = self._clock() - self._sent_at
        if self._srtt is None:
            self._srtt, self._rttvar = rtt, rtt / 2
        else:
            self._rttvar = 0.75 * self._rttvar + 0.25 * abs(self._srtt - rtt)
            self._srtt = 0.875 * self._srtt + 0.125 * rtt

    def _timeout(self) -> float:
        base = self._min_timeout if self._srtt is None else self._srtt + max(0.05, 4 * self._rttvar)
        base = min(self._max_timeout, max(self._min_timeout, base))
        return min(self._max_timeout, base * (2 ** max(0, self._tries - 1)))

    def _transmit(self, opcode: int, payload: bytes, offset: int = 0, retry: bool = False) -> None:
        self._request = (opcode, payload, offset)
        self._tries = self._tries + 1 if retry else 1
        self._sampled = False
        self._sent_at = self._clock()
        self._send(self.target[0], self.target[1], payload)

    def _request_op(self, opcode: int, *, session: int = 0, offset: int = 0, data: bytes = b"",
                    size: int | None = None) -> None:
        self._transmit(opcode, FtpPacket.request(self._seq, session, opcode, offset, data, size), offset)

    def _next_job(self) -> None:
        """Start the next request: from the lane after the one served last that has one waiting (round robin)."""
        names = list(self._lanes)
        if self._last_lane in self._lanes:
            at = names.index(self._last_lane) + 1
            names = names[at:] + names[:at]
        lane = next((name for name in names if self._lanes[name]), None)
        if lane is None:
            self._job = None
            return
        self._job, self._job_lane, self._last_lane = self._lanes[lane].popleft(), lane, lane
        self.started_wall = time.time()
        path = self._job.path.encode("utf-8")
        if len(path) >= MAX_DATA:
            self._finish(None, "path too long")
            return
        opcode = Op.CALC_FILE_CRC32 if self._job.crc_only else Op.OPEN_FILE_RO
        if self._job.upload is not None:
            opcode = Op.CREATE_FILE
        self._request_op(opcode, session=self.session, data=path + b"\0", size=len(path))

    def _on_reply(self, opcode: int, offset: int, reply: FtpPacket) -> None:
        job = self._job
        assert job is not None
        if opcode == Op.CALC_FILE_CRC32:
            if reply.opcode == Op.NAK:
                self._finish(None, f"CRC failed: {reply.error_text()}", terminate=False)
            else:
                self._finish(reply.data[:4].ljust(4, b"\0"), "", terminate=False)
            return
        if opcode == Op.CREATE_FILE:
            if reply.opcode == Op.NAK:
                self._finish(None, f"create failed: {reply.error_text()}", terminate=False)
                return
            job.session = reply.session
            self._write_next()
        elif opcode == Op.WRITE_FILE:
            if reply.opcode == Op.NAK:
                self._finish(None, f"write failed at {offset}: {reply.error_text()}")
                return
            job.written = max(job.written, offset + min(MAX_DATA, len(job.upload or b"") - offset))
            self._write_next()
        elif opcode == Op.OPEN_FILE_RO:
            if reply.opcode == Op.NAK:
                self._finish(None, f"open failed: {reply.error_text()}", terminate=False)
                return
            job.session = reply.session
            size = struct.unpack_from("<I", reply.data.ljust(4, b"\0"))[0] or None  # 0: read to EOF
            if size is not None and size > self.max_file_bytes:
                self._finish(None, f"file of {size} bytes refused: over the {self._cap_text()} cap")
                return
            job.start(size)
            self._continue()
        elif opcode == Op.READ_FILE:
            if reply.opcode == Op.NAK:
                if reply.data[:1] == bytes([FtpErr.EOF]):
                    if job.size is not None:
                        self._finish(None, f"file ended at {offset}, before its announced {job.size} bytes")
                        return
                    job.size = len(job.buf)  # the end of a file of unknown size: what we have is all
                    job.have = bytearray(b"\1" * job.size)
                    self._continue()
                else:
                    self._finish(None, f"read failed at {offset}: {reply.error_text()}")
                return
            self._store(offset, reply.data)
            if len(job.buf) > self.max_file_bytes:  # a file of unknown size that never ends
                self._finish(None, f"file refused: over the {self._cap_text()} cap at offset {offset}")
                return
            self._continue()
        elif opcode == Op.TERMINATE_SESSION:
            if job.upload is not None and reply.opcode == Op.NAK and not job.error:
                job.error = f"refused: {reply.error_text()}"
            self._complete()

    def _cap_text(self) -> str:
        cap = self.max_file_bytes
        return f"{cap // (1 << 20)} MiB" if cap % (1 << 20) == 0 else f"{cap}-byte"

    def _write_next(self) -> None:
        """The next piece of an upload, or the closing request (the server takes the file then) after the last."""
        job = self._job
        assert job is not None and job.upload is not None and job.session is not None
        if job.written >= len(job.upload):
            self._terminate()
            return
        chunk = job.upload[job.written : job.written + MAX_DATA]
        self._request_op(Op.WRITE_FILE, session=job.session, offset=job.written, data=chunk)

    def _on_burst(self, reply: FtpPacket) -> None:
        job = self._job
        assert job is not None
        self._seq = (reply.seq + 1) & 0xFFFF
        self._sent_at = self._clock()  # progress: the timeout counts from the latest packet
        self._tries = 1
        if reply.opcode == Op.NAK:
            if reply.data[:1] != bytes([FtpErr.EOF]) or job.hole() is not None:
                self._request = None
                self._finish(None, f"burst read failed: {reply.error_text()}")
                return
        else:
            self._store(reply.offset, reply.data)
        if reply.opcode == Op.NAK or reply.burst_complete or job.hole() is None:
            self._request = None
            self._continue()

    def _store(self, offset: int, data: bytes) -> None:
        job = self._job
        assert job is not None
        self.bytes_read += job.store(offset, data)

    def _continue(self) -> None:
        """Ask for what is still missing, or close the session when nothing is."""
        job = self._job
        assert job is not None and job.session is not None
        if job.size is None:
            self._request_op(Op.READ_FILE, session=job.session, offset=len(job.buf), size=MAX_DATA)
            return
        hole = job.hole()
        if hole is None:
            self._terminate()
        elif job.have.count(0) <= 2 * MAX_DATA or not self._burst:
            offset, length = hole
            self._request_op(Op.READ_FILE, session=job.session, offset=offset, size=min(MAX_DATA, length))
        else:
            self._request_op(Op.BURST_READ_FILE, session=job.session, offset=hole[0], size=MAX_DATA)

    def _terminate(self) -> None:
        job = self._job
        assert job is not None
        self._request_op(Op.TERMINATE_SESSION, session=job.session or 0)

    def _complete(self) -> None:
        job = self._job
        assert job is not None
        if job.error:
            self._finish(None, job.error, terminate=False)
            return
        if job.upload is not None:
            self._finish(job.upload, "", terminate=False)
            return
        data = bytes(job.buf)
        if job.size is not None and len(data) != job.size:
            self._finish(None, f"got {len(data)} of {job.size} bytes", terminate=False)
            return
        self.files_done += 1
        self._finish(data, "", terminate=False)

    def _finish(self, data: bytes | None, error: str, terminate: bool = True) -> None:
        """End the current job; a failure mid-session first closes the session so the server frees it."""
        job = self._job
        assert job is not None
        if data is None and terminate and job.session is not None and not job.error:
            job.error = error
            self._terminate()
            return
        self._job = None
        self._request = None
        self._finishing = True  # what ``done`` asks for waits its lane's turn, like everything else
        try:
            job.done(job.path, data, error)
        except Exception:  # a caller's bug must not stall the queue
            log.exception("FTP callback for %s failed", job.path)
        finally:
            self._finishing = False
        if self._job is None:
            self._next_job()

