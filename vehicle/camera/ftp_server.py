"""A MAVLink FTP server core over a virtual, read-mostly file tree (no transport in here).

``FtpServer.handle`` turns one request payload into its immediate replies; BurstReadFile replies are produced one
at a time by ``next_burst`` so the link budget decides when each bulk packet goes (and a newer burst request
replaces an older one instead of piling up). The interoperability rules come from REFERENCE.md section 3: replies
echo the request opcode and carry seq + 1, OpenFileRO's ACK carries the size as uint32 LE, reads return at most
239 bytes, TerminateSession is acknowledged, a retransmitted request is answered again, paths are NUL terminated
and ``..`` cannot leave the tree (nothing on disk is reachable at all: every file is a callable in memory).

Many clients at once (QGroundControl, BlueOS, MAVProxy, the surface tool): the server remembers only the last
reply per requester and resends it only for a byte-identical request within a few seconds (MAVLink FTP's
retransmission: a client repeats its last request when the answer was lost), so a restarted client that reuses
seq numbers, or a new OpenFileRO, always gets fresh answers; sessions belong to the link that opened them
(``ftp_sessions``); every refused or failed request gets a NAK with its error code (FileNotFound, Fail,
Fail+errno, NoSessionsAvailable, ...), never silence. Listings come from each file's size metadata, so listing
the frames never produces (JPEG-encodes) them.
"""

from __future__ import annotations

import logging
import posixpath
import struct
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from vehicle.camera.ftp_sessions import Requester, Session, SessionTable
from vehicle.protocol.ftp import MAX_DATA, FtpErr, FtpPacket, Op, ack, crc32_ardupilot, nak

__all__ = ["FtpServer", "VirtualTree", "clean_path", "crc32_ardupilot"]

log = logging.getLogger(__name__)

BURST_PACKETS = 32
"""Packets per BurstReadFile answer before burst_complete asks the client for more."""
RETRANSMIT_WINDOW_S = 5.0
"""A repeated request is a retransmission only this soon after the first (a restarted client reuses seqs)."""
MAX_REQUESTERS = 256
"""Last replies kept for this many requesters (spoofed ids by the thousand must not grow the table)."""


def clean_path(raw: str) -> str | None:
    """An absolute, normalised path inside the served root, or None when it tries to climb out with ``..``."""
    parts = [p for p in raw.replace("\\", "/").split("/") if p not in ("", ".")]
    if ".." in parts:
        return None
    return posixpath.join("/", *parts)


class VirtualTree:
    """Files as callables returning bytes, and upload slots as callables taking bytes; directories are implied.

    The surface link keeps it current (a thumbnail appears when a frame enters the summary, goes when it leaves);
    reading through a callable means the index and full frames are produced only when someone asks.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._files: dict[str, Callable[[], bytes]] = {}
        self._sizes: dict[str, Callable[[], int]] = {}
        self._uploads: dict[str, Callable[[bytes], None]] = {}

    def put(self, path: str, content: bytes | Callable[[], bytes], *, size: Callable[[], int] | None = None) -> None:
        """``content`` is the file or how to produce it; ``size`` says what a listing shows without producing it
        (a file produced on demand with no ``size`` lists as 0 bytes until then: the open's ACK has the truth)."""
        key = clean_path(path) or path
        if callable(content):
            getter, sizer = content, size or (lambda: 0)
        else:
            data = bytes(content)
            length = len(data)
            getter, sizer = (lambda: data), (lambda: length)
        with self._lock:
            self._files[key] = getter
            self._sizes[key] = sizer

    def remove(self, path: str) -> None:
        key = clean_path(path) or path
        with self._lock:
            self._files.pop(key, None)
            self._sizes.pop(key, None)

    def uploadable(self, path: str, on_upload: Callable[[bytes], None]) -> None:
        """``path`` may be written by a client (when the server is writable); ``on_upload`` gets the whole file."""
        with self._lock:
            self._uploads[clean_path(path) or path] = on_upload

    def read(self, path: str) -> bytes | None:
        with self._lock:
            getter = self._files.get(path)
        return None if getter is None else getter()

    def is_dir(self, path: str) -> bool:
        prefix = path.rstrip("/") + "/"
        with self._lock:
            names = list(self._files) + list(self._uploads)
        return path == "/" or any(n.startswith(prefix) for n in names)

    def listdir(self, path: str) -> list[tuple[str, bool, int]] | None:
        """Sorted (name, is_dir, size) below ``path``, or None when it is not a directory."""
        if not self.is_dir(path):
            return None
        prefix = path.rstrip("/") + "/"
        with self._lock:
            sizes = dict(self._sizes)
            names = set(self._files) | set(self._uploads)
        entries: dict[str, tuple[str, bool, int]] = {}
        for name in names:
            if not name.startswith(prefix):
                continue
            head, _, rest = name[len(prefix):].partition("/")
            if rest:
                entries[head] = (head, True, 0)
            elif head not in entries:
                sizer = sizes.get(name)
                entries[head] = (head, False, sizer() if sizer else 0)
        return [entries[k] for k in sorted(entries)]

    def upload_target(self, path: str) -> Callable[[bytes], None] | None:
        with self._lock:
            return self._uploads.get(path)


class FtpServer:
    """MAVLink FTP over a ``VirtualTree``: read-only unless ``writable``; ``max_sessions`` open files at once.

    Sessions are kept per client, and an open is granted the session number the client asked with: pymavlink's
    mavftp adopts whatever the ACK says, but MAVSDK 4 keeps using its own number, so echoing it serves both. An
    open on a number the same client still holds replaces that session (the client has abandoned it). Who may
    take a session when the table is full, and which link owns one, is ``SessionTable``'s rule; a busy server
    answers NoSessionsAvailable rather than close another client's file in use.
    """

    def __init__(self, tree: VirtualTree, *, writable: bool = False, max_sessions: int = 8,
                 clock: Callable[[], float] = time.monotonic, per_requester: int = 2,
                 reserve_signed: int = 0) -> None:
        self.tree = tree
        self.writable = writable
        self.max_sessions = max_sessions
        self._clock = clock
        self._lock = threading.Lock()
        self.sessions = SessionTable(max_sessions, per_requester=per_requester, reserve_signed=reserve_signed)
        self._last: OrderedDict[tuple[Requester, bool], tuple[float, bytes, list[bytes]]] = OrderedDict()
        """Per requester (and whether it signs): when, the request's bytes and the replies it got."""
        self.requests = 0
        self.retransmits_answered = 0
        self.naks: dict[int, int] = {}
        """NAKs sent, by error code (what a status line or a test checks)."""

    # ---- requests -------------------------------------------------------------------------------------------

    def handle(self, payload: bytes, requester: Requester, signed: bool = False) -> list[bytes]:
        """Immediate reply payloads (251 bytes each) for one request; bursts continue through ``next_burst``.

        ``signed``: the request carried a valid signature (the sessions it opens are then its link's alone)."""
        try:
            req = FtpPacket.unpack(payload)
        except ValueError as err:
            log.debug("FTP: ignoring malformed request: %s", err)
            return []
        if req.opcode in (Op.ACK, Op.NAK):
            return []
        owner = (requester, signed)
        raw = bytes(payload)
        now = self._clock()
        with self._lock:
            self.requests += 1
            last = self._last.get(owner)
            if (req.opcode != Op.BURST_READ_FILE and last is not None and last[1] == raw
                    and now - last[0] <= RETRANSMIT_WINDOW_S):
                self.retransmits_answered += 1  # the very same bytes again: our answer was lost
                return list(last[2])
        try:
            pre = self._prefetch(req)  # outside the lock: a file may be produced on demand (a full frame's JPEG)
            with self._lock:
                upload = self._finished_upload(req, requester, signed)
                if upload is None:
                    packets = self._dispatch(req, requester, signed, pre)
            if upload is not None:  # the receiver of an upload may take its time (new queries are encoded)
                packets = [self._commit(req, upload)]
        except OSError as err:
            log.warning("FTP: request %d failed: %s", req.opcode, err)
            packets = [nak(req, FtpErr.FAIL_ERRNO, errno=err.errno or 5)]
        except Exception:
            log.exception("FTP: request %d failed", req.opcode)
            packets = [nak(req, FtpErr.FAIL)]
        replies = [p.pack() for p in packets]
        with self._lock:
            for p in packets:
                if p.opcode == Op.NAK:
                    self.naks[p.data[0]] = self.naks.get(p.data[0], 0) + 1
            self._last.pop(owner, None)
            if req.opcode != Op.BURST_READ_FILE:  # only the last reply per requester is ever resent
                self._last[owner] = (now, raw, replies)
                while len(self._last) > MAX_REQUESTERS:
                    self._last.popitem(last=False)
        return replies

    def refuse(self, payload: bytes, error: FtpErr = FtpErr.FILE_PROTECTED) -> list[bytes]:
        """The NAK for a request the link refused before it reached us (an unsigned write on a signed link):
        every request gets an answer."""
        try:
            req = FtpPacket.unpack(payload)
        except ValueError:
            return []
        if req.opcode in (Op.ACK, Op.NAK):
            return []
        with self._lock:
            self.naks[int(error)] = self.naks.get(int(error), 0) + 1
        return [nak(req, error).pack()]

    def _prefetch(self, req: FtpPacket) -> object:
        """What the tree holds for a request that reads it: bytes, a listing, or None (not there / no such op)."""
        if req.opcode not in (Op.LIST_DIRECTORY, Op.OPEN_FILE_RO, Op.CALC_FILE_CRC32):
            return None
        path = clean_path(req.path())
        if path is None:
            return None
        return self.tree.listdir(path) if req.opcode == Op.LIST_DIRECTORY else self.tree.read(path)

    def _dispatch(self, req: FtpPacket, who: Requester, signed: bool, pre: object = None) -> list[FtpPacket]:
        op = req.opcode
        if op == Op.NONE:
            return [ack(req)]
        if op == Op.RESET_SESSIONS:
            self.sessions.reset(who, signed)
            return [ack(req)]
        if op == Op.TERMINATE_SESSION:
            return [self._terminate(req, who, signed)]
        if op == Op.LIST_DIRECTORY:
            return [self._list(req, pre)]
        if op == Op.OPEN_FILE_RO:
            return [self._open_ro(req, who, signed, pre)]
        if op == Op.READ_FILE:
            return [self._read(req, who, signed)]
        if op == Op.BURST_READ_FILE:
            return self._burst_start(req, who, signed)
        if op == Op.CALC_FILE_CRC32:
            return [self._crc(req, pre)]
        if op in (Op.CREATE_FILE, Op.OPEN_FILE_WO, Op.WRITE_FILE, Op.TRUNCATE_FILE, Op.REMOVE_FILE):
            if not self.writable:
                return [nak(req, FtpErr.FILE_PROTECTED)]
            return [self._write_op(req, who, signed)]
        if op in (Op.CREATE_DIRECTORY, Op.REMOVE_DIRECTORY) and not self.writable:
            return [nak(req, FtpErr.FILE_PROTECTED)]
        return [nak(req, FtpErr.UNKNOWN_COMMAND)]

    def _session(self, req: FtpPacket, who: Requester, signed: bool) -> tuple[Session | None, FtpPacket | None]:
        """The session a request names, or the NAK that answers it (none such, or another link's)."""
        sess, foreign = self.sessions.find(who, req.session, signed, self._clock())
        if foreign:
            return None, nak(req, FtpErr.FAIL)
        if sess is None:
            return None, nak(req, FtpErr.INVALID_SESSION)
        return sess, None

    def _new_session(self, req: FtpPacket, who: Requester, signed: bool, path: str, data: bytes,
                     writing: bool) -> FtpPacket:
        """The ACK granting the session the client asked for, or the NAK: NoSessionsAvailable when every session
        is held by active clients, Fail when that session is another (signed) link's."""
        session = Session(who, path, bytearray(data), writing)
        refused = self.sessions.grant(who, req.session, signed, session, self._clock())
        if refused == "foreign":
            return nak(req, FtpErr.FAIL)
        if refused is not None:
            return nak(req, FtpErr.NO_SESSIONS_AVAILABLE)
        if writing:
            return ack(req, session=req.session)
        return ack(req, session=req.session, data=struct.pack("<I", len(data)))

    def _terminate(self, req: FtpPacket, who: Requester, signed: bool) -> FtpPacket:
        sess, refusal = self._session(req, who, signed)
        if sess is None:
            return refusal
        self.sessions.end(who, req.session)
        return ack(req)

    def _finished_upload(self, req: FtpPacket, who: Requester, signed: bool) -> Session | None:
        """A TerminateSession that closes a written file: the session, taken out (called with the lock held)."""
        if req.opcode != Op.TERMINATE_SESSION:
            return None
        sess, _ = self._session(req, who, signed)
        if sess is None or not sess.writing:
            return None
        self.sessions.end(who, req.session)
        return sess

    def _commit(self, req: FtpPacket, sess: Session) -> FtpPacket:
        """Hand a closed upload to its receiver (without the lock held); its refusal is the client's NAK."""
        target = self.tree.upload_target(sess.path)
        try:
            if target is None:
                raise ValueError("not uploadable")
            target(bytes(sess.data))
        except OSError as err:  # the receiver could not store it: the client learns the errno
            log.warning("FTP: upload to %s failed: %s", sess.path, err)
            return nak(req, FtpErr.FAIL_ERRNO, errno=err.errno or 5)
        except Exception as err:  # refused (a queries file the product rejects), whatever error type says so
            log.warning("FTP: upload to %s refused: %s", sess.path, err)
            return nak(req, FtpErr.FAIL)
        return ack(req)

    def _list(self, req: FtpPacket, entries) -> FtpPacket:
        if entries is None:
            return nak(req, FtpErr.FILE_NOT_FOUND)
        if req.offset >= len(entries):
            return nak(req, FtpErr.EOF)
        out = b""
        for name, is_dir, size in entries[req.offset:]:
            item = (f"D{name}" if is_dir else f"F{name}\t{size}").encode("utf-8") + b"\0"
            if len(out) + len(item) > MAX_DATA:
                break
            out += item
        if not out:
            return nak(req, FtpErr.FAIL)
        return ack(req, data=out)

    def _open_ro(self, req: FtpPacket, who: Requester, signed: bool, data) -> FtpPacket:
        if data is None:
            return nak(req, FtpErr.FILE_NOT_FOUND)
        return self._new_session(req, who, signed, clean_path(req.path()) or "", data, writing=False)

    def _read(self, req: FtpPacket, who: Requester, signed: bool) -> FtpPacket:
        sess, refusal = self._session(req, who, signed)
        if sess is None or sess.writing:
            return refusal or nak(req, FtpErr.INVALID_SESSION)
        if req.offset >= len(sess.data):
            return nak(req, FtpErr.EOF)
        want = req.size if 0 < req.size <= MAX_DATA else MAX_DATA
        return ack(req, data=bytes(sess.data[req.offset: req.offset + want]))

    def _burst_start(self, req: FtpPacket, who: Requester, signed: bool) -> list[FtpPacket]:
        sess, refusal = self._session(req, who, signed)
        if sess is None or sess.writing:
            return [refusal or nak(req, FtpErr.INVALID_SESSION)]
        if req.offset >= len(sess.data):
            sess.burst_offset = None
            return [nak(req, FtpErr.EOF)]
        sess.burst_offset = req.offset
        sess.burst_seq = (req.seq + 1) & 0xFFFF
        sess.burst_left = BURST_PACKETS
        sess.burst_session = req.session
        return []

    def _crc(self, req: FtpPacket, data) -> FtpPacket:
        if data is None:
            return nak(req, FtpErr.FILE_NOT_FOUND)
        return ack(req, data=struct.pack("<I", crc32_ardupilot(data)))

    def _write_op(self, req: FtpPacket, who: Requester, signed: bool) -> FtpPacket:
        op = req.opcode
        if op == Op.WRITE_FILE:
            sess, refusal = self._session(req, who, signed)
            if sess is None or not sess.writing:
                return refusal or nak(req, FtpErr.INVALID_SESSION)
            end = req.offset + len(req.data)
            if end > 1 << 20:
                return nak(req, FtpErr.INVALID_DATA_SIZE)
            if len(sess.data) < end:
                sess.data.extend(b"\0" * (end - len(sess.data)))
            sess.data[req.offset:end] = req.data
            return ack(req)
        path = clean_path(req.path())
        target = None if path is None else self.tree.upload_target(path)
        if target is None:
            exists = path is not None and self.tree.read(path) is not None
            return nak(req, FtpErr.FILE_PROTECTED if exists else FtpErr.FAIL)
        if op == Op.REMOVE_FILE:
            return nak(req, FtpErr.FILE_PROTECTED)
        current = self.tree.read(path) or b""
        if op == Op.TRUNCATE_FILE:
            target(current[: req.offset])  # a refusal raises: handle() answers it with a NAK
            return ack(req)
        start = b"" if op == Op.CREATE_FILE else current
        return self._new_session(req, who, signed, path, start, writing=True)

    # ---- bursts ---------------------------------------------------------------------------------------------

    def next_burst(self, signed: bool | None = None) -> tuple[Requester, bytes] | None:
        """The next bulk packet of the oldest running burst (signed links' first), or None when none is running;
        ``signed``: of signed (True) or unsigned (False) links' sessions only."""
        with self._lock:
            for sess in self.sessions.values():
                if sess.burst_offset is None or (signed is not None and sess.signed != signed):
                    continue
                offset = sess.burst_offset
                chunk = bytes(sess.data[offset: offset + MAX_DATA])
                nxt = offset + len(chunk)
                sess.burst_left -= 1
                last = nxt >= len(sess.data) or sess.burst_left <= 0
                pkt = FtpPacket(seq=sess.burst_seq, session=sess.burst_session, opcode=Op.ACK,
                                req_opcode=Op.BURST_READ_FILE, offset=offset, data=chunk, burst_complete=last)
                sess.burst_seq = (sess.burst_seq + 1) & 0xFFFF
                sess.burst_offset = None if last else nxt
                sess.used = self._clock()
                return sess.requester, pkt.pack()
        return None
