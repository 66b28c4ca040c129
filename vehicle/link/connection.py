"""The one MAVLink connection of the companion: a receive thread, a writer thread, a 1 Hz heartbeat, pub/sub.

Everything MAVLink in the process goes through one ``MavLink``: other parts subscribe to the message types they
care about and ``send`` pymavlink message objects, which the link packs as MAVLink 2 with *its* system and
component id and sequence number. Opening, reconnecting (TCP and serial, with back-off) and reading happen on the
receive thread, which only parses and dispatches (``_dispatch``, the one place incoming messages are accepted);
every outgoing message is packed once (``_pack``, the one place) and written on the writer thread; sending
before a peer is known writes 0 bytes.

pymavlink's ``mavutil`` opens the transports; packing and parsing use the MAVLink 2 ``ardupilotmega`` dialect
directly, so the wire version never depends on the environment or on which module imported pymavlink first.
"""

from __future__ import annotations

import collections
import logging
import queue
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vehicle.errors import UsageError
from vehicle.link.signing import LinkSigning
from vehicle.link.warning_bucket import WarningBucket
from vehicle.settings import MavlinkConfig

log = logging.getLogger(__name__)

MAV_TYPE_CAMERA = mavlink2.MAV_TYPE_CAMERA
MAVLinkMessage = mavlink2.MAVLink_message

# Heartbeats of these types are never the autopilot, whatever their ``autopilot`` field says.
_NOT_AUTOPILOT_TYPES = frozenset({
    mavlink2.MAV_TYPE_GCS,
    mavlink2.MAV_TYPE_CAMERA,
    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
    mavlink2.MAV_TYPE_GIMBAL,
    mavlink2.MAV_TYPE_ADSB,
})
_SCHEMES = ("udpin", "udpout", "tcp", "tcpin")
_POLL_S = 0.1
_MAGIC = (mavlink2.PROTOCOL_MARKER_V2, mavlink2.PROTOCOL_MARKER_V1)
_UDP_BURST = 64
_SERIAL_WRITE_TIMEOUT_S = 0.2
_SEND_WAIT_S = 2.0
BAD_LOG_S = 10.0
"""At most one log line per this many seconds about bad input (the count is in ``rx_bad``)."""
_UDP_RCVBUF = 1 << 20  # room for a burst (a parameter download, a busy router) while the thread is descheduled
HEARTBEAT_PERIOD_S = 1.0


def next_heartbeat(due: float, now: float, period: float = HEARTBEAT_PERIOD_S) -> float:
    """When the heartbeat after the one due at ``due`` (sent at ``now``) is due: on a fixed grid, so that waking up
    to a poll late does not push every later beat back (it gave 0.95 Hz); after a stall of more than a period, a
    new grid from now, with no burst of beats to catch up."""
    due += period
    return due if due > now else now + period


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string: ``scheme`` is udpin | udpout | tcp | tcpin | serial."""

    scheme: str
    address: str
    baud: int = 115200

    @property
    def reconnects(self) -> bool:
        """TCP client and serial links are re-opened after a failure; UDP and TCP servers just wait."""
        return self.scheme in ("tcp", "serial")

    def __str__(self) -> str:
        return f"{self.address},{self.baud}" if self.scheme == "serial" else f"{self.scheme}:{self.address}"


@dataclass
class _Outgoing:
    """One packet handed to the writer thread, and how many bytes it became."""

    item: MAVLinkMessage | bytes
    done: threading.Event = field(default_factory=threading.Event)
    sent: int = 0


def parse_connection(connection: str) -> Endpoint:
    """Check a connection string up front so a typo is a one-line error, not a thread dying later."""
    text = (connection or "").strip()
    scheme, sep, rest = text.partition(":")
    if sep and scheme in _SCHEMES:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise UsageError(f"mavlink connection {connection!r}: expected {scheme}:HOST:PORT")
        return Endpoint(scheme, f"{host}:{int(port)}")
    if text.startswith("/") or text.upper().startswith("COM"):
        device, _, baud = text.partition(",")
        if baud and not baud.isdigit():
            raise UsageError(f"mavlink connection {connection!r}: baud rate must be a number")
        return Endpoint("serial", device, int(baud) if baud else 115200)
    raise UsageError(
        f"mavlink connection {connection!r}: expected udpin:, udpout:, tcp:, tcpin:HOST:PORT or /dev/DEVICE,BAUD"
    )


def is_autopilot_heartbeat(msg: MAVLinkMessage) -> bool:
    """The autopilot is a submarine, or anything with a real autopilot that is not a GCS, camera or computer."""
    if msg.get_type() != "HEARTBEAT":
        return False
    if msg.type == mavlink2.MAV_TYPE_SUBMARINE:
        return True
    return msg.type not in _NOT_AUTOPILOT_TYPES and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID


class MavLink:
    """One MAVLink connection owned by its own threads; see the module docstring."""

    def __init__(
        self,
        connection: str,
        cfg: MavlinkConfig,
        *,
        clock: Callable[[], float] = time.monotonic,
        name: str = "companion",
        heartbeat: bool = True,
        mav_type: int = MAV_TYPE_CAMERA,
    ) -> None:
        self.endpoint = parse_connection(connection)
        self.cfg = cfg
        self.clock = clock
        self.name = name
        self.mav_type = mav_type
        self._send_heartbeat = heartbeat
        self._configured_system = cfg.system_id
        self.system_id: int = cfg.system_id or 1
        self.component_id: int = cfg.component_id
        self.autopilot: tuple[int, int] | None = None
        self.autopilot_alive = False
        self.healthy: Callable[[], bool] | None = None
        self.tx_bytes = 0
        self.rx_bytes = 0
        self.rx_messages = 0
        self.rx_bad = 0
        self._bad_log = WarningBucket(burst=1, refill_s=BAD_LOG_S)
        self.rx_unknown = 0
        self.tx_messages = 0
        self.reconnects = 0
        self.rx_longest_s = 0.0
        """The longest the receive loop spent on one datagram (parse + dispatch), wall time: its worst stall so
        far, including time the thread was descheduled (a loaded machine, the GIL)."""
        self.rx_longest_cpu_s = 0.0
        """The same in the thread's own CPU time: the work done on the loop, without waiting or being preempted."""
        self.rx_slow = 0
        """Datagrams that held the loop longer than 50 ms (wall)."""
        self.last_autopilot_heartbeat: MAVLinkMessage | None = None
        self._autopilot_signed = False
        self.foreign_autopilot_heartbeats = 0
        """Autopilot heartbeats from another system or component than the autopilot found first: ignored (the
        identity is settled once; a stranger's HEARTBEAT must not move it)."""
        self._last_autopilot_seen: float | None = None
        self._heard: queue.SimpleQueue[float] = queue.SimpleQueue()
        """When the receive thread heard the autopilot's heartbeats: drained by the timer thread, the one owner of
        ``autopilot_alive`` (found and lost are decided, and reported, on that one thread, in order)."""
        self._conn: mavutil.mavfile | None = None
        self._tx = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=self.component_id)
        self.signing = LinkSigning.from_settings(cfg, name=name)
        self._rx = self._new_parser()
        self._send_lock = threading.Lock()
        self._out_cond = threading.Condition()
        self._outbox: collections.deque[_Outgoing] = collections.deque()
        self._writer: threading.Thread | None = None
        self._subs_lock = threading.Lock()
        self._subs: list[tuple[Callable[[MAVLinkMessage], None], frozenset[str] | None]] = []
        self._autopilot_cbs: list[Callable[[bool], None]] = []
        self._refused_cbs: list[Callable[[MAVLinkMessage, str], None]] = []
        self._stop = threading.Event()
        self._opened = threading.Event()
        self._found = threading.Event()
        self._threads: list[threading.Thread] = []

    # ----------------------------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Start the receive and heartbeat threads; returns at once (the connection opens on the thread)."""
        if self._threads:
            return
        self._stop.clear()
        self._writer = threading.Thread(target=self._writer_loop, name=f"{self.name}-mavlink-tx", daemon=True)
        self._threads = [
            threading.Thread(target=self._receive_loop, name=f"{self.name}-mavlink-rx", daemon=True),
            threading.Thread(target=self._timer_loop, name=f"{self.name}-mavlink-hb", daemon=True),
            self._writer,
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop the threads (the writer first sends what was handed to it) and close the connection; safe to
        call twice."""
        self._stop.set()
        with self._out_cond:
            self._out_cond.notify_all()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []
        self._writer = None
        self._close()

    def __enter__(self) -> MavLink:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_open(self, timeout: float) -> bool:
        """True once the transport is open (a UDP server is then bound and can be sent to)."""
        return self._opened.wait(timeout)

    def wait_autopilot(self, timeout: float) -> bool:
        """True as soon as the autopilot's heartbeat is current (for start-up and tests; the link never needs it)."""
        return self._found.wait(timeout)

    # ----------------------------------------------------------------------------------------------- pub/sub
    def subscribe(
        self, callback: Callable[[MAVLinkMessage], None], types: Iterable[str] | None = None
    ) -> Callable[[], None]:
        """Call ``callback(msg)`` on the receive thread for every message (or those types); returns unsubscribe."""
        entry = (callback, frozenset(types) if types is not None else None)
        with self._subs_lock:
            self._subs = [*self._subs, entry]

        def unsubscribe() -> None:
            with self._subs_lock:
                self._subs = [s for s in self._subs if s is not entry]

        return unsubscribe

    def on_autopilot(self, callback: Callable[[bool], None]) -> None:
        """``callback(True)`` when the autopilot's heartbeat is found (again), ``callback(False)`` when lost; both on
        the link's timer thread, in the order they happened."""
        self._autopilot_cbs.append(callback)

    def on_refused(self, callback: Callable[[MAVLinkMessage, str], None]) -> None:
        """``callback(msg, reason)`` on the receive thread for each message addressed to us that signing refused
        (unsigned, bad signature, replayed, stale): a protocol that must answer every request (FTP) NAKs it."""
        self._refused_cbs.append(callback)

    def send(self, msg: MAVLinkMessage) -> int:
        """Pack ``msg`` with our ids and sequence and write it; the wire bytes written (0: no peer yet).

        This is the one send path: every message is packed exactly once and written on the link's one writer
        thread, in the order ``send`` was called (pymavlink's ``pack`` writes into the message object, so it must
        never run on two threads; the sequence numbers leave in order). The caller waits for its packet to be
        written and gets the byte count, with which budgets charge what was really sent.
        """
        return self._through_writer(msg)

    def send_raw(self, packet: bytes) -> int:
        """Write an already packed MAVLink packet unchanged (log replay keeps the recorded ids and sequence)."""
        return self._through_writer(bytes(packet))

    @property
    def connected(self) -> bool:
        conn = self._conn
        return conn is not None and self._has_peer(conn)

    def stats(self) -> dict[str, object]:
        """Counters for status reports and logs."""
        return {
            "connection": str(self.endpoint), "system_id": self.system_id, "component_id": self.component_id,
            "autopilot": self.autopilot, "autopilot_alive": self.autopilot_alive, "tx_bytes": self.tx_bytes,
            "tx_messages": self.tx_messages, "rx_bytes": self.rx_bytes, "rx_messages": self.rx_messages,
            "rx_bad": self.rx_bad, "rx_unknown": self.rx_unknown, "reconnects": self.reconnects,
            "foreign_autopilot_heartbeats": self.foreign_autopilot_heartbeats,
            "signing": self.signing.stats(),
            "rx_longest_ms": round(self.rx_longest_s * 1000.0, 2),
            "rx_longest_cpu_ms": round(self.rx_longest_cpu_s * 1000.0, 2), "rx_slow": self.rx_slow,
        }

    # ----------------------------------------------------------------------------------------------- internals
    def _through_writer(self, item: MAVLinkMessage | bytes) -> int:
        writer = self._writer
        if writer is None or threading.current_thread() is writer or self._stop.is_set():
            # not started, or stopping: no writer to wait for (the send lock still keeps packing one at a time)
            return self._write(item)
        job = _Outgoing(item)
        with self._out_cond:
            self._outbox.append(job)
            self._out_cond.notify()
        if not job.done.wait(_SEND_WAIT_S):  # a stalled serial port: the packet may still go, and is counted then
            return 0
        return job.sent

    def _writer_loop(self) -> None:
        while True:
            with self._out_cond:
                while not self._outbox and not self._stop.is_set():
                    self._out_cond.wait(_POLL_S)
                if not self._outbox:
                    return
                job = self._outbox.popleft()
            job.sent = self._write(job.item)
            job.done.set()

    def _write(self, item: MAVLinkMessage | bytes) -> int:
        """Pack (unless raw) and write one packet; the bytes written."""
        with self._send_lock:
            conn = self._conn
            if conn is None or not self._has_peer(conn):
                return 0
            try:
                buf = item if isinstance(item, bytes) else self._pack(item)
            except Exception as err:
                log.warning("%s: cannot pack %r: %s", self.name, item, err)
                return 0
            self.tx_bytes += len(buf)  # counted before the write: a peer may answer before write() returns
            self.tx_messages += 1
            try:
                conn.write(buf)
            except Exception as err:  # a dying socket must not reach the caller's loop
                log.debug("%s: send failed: %s", self.name, err)
                self.tx_bytes -= len(buf)
                self.tx_messages -= 1
                return 0
            return len(buf)

    def _pack(self, msg: MAVLinkMessage) -> bytes:
        """The one place an outgoing message becomes bytes (called with the send lock held)."""
        self.signing.prepare(self._tx)  # with a key: the next timestamp, persisted ahead of use
        buf = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        self._tx.total_packets_sent += 1
        self._tx.total_bytes_sent += len(buf)
        return buf

    @staticmethod
    def _new_parser() -> mavlink2.MAVLink:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        return parser

    def _has_peer(self, conn: mavutil.mavfile) -> bool:
        scheme = self.endpoint.scheme
        if scheme == "udpin":
            return bool(conn.clients)
        if scheme in ("tcp", "tcpin"):
            return conn.port is not None
        return True

    def _open(self) -> mavutil.mavfile:
        ep = self.endpoint
        kwargs = {"source_system": self.system_id, "source_component": self.component_id}
        if ep.scheme == "serial":
            conn = mavutil.mavlink_connection(ep.address, baud=ep.baud, **kwargs)
            conn.port.write_timeout = _SERIAL_WRITE_TIMEOUT_S  # a stalled port must not hold up a sender
            return conn
        if ep.scheme == "tcp":
            return mavutil.mavlink_connection(f"tcp:{ep.address}", retries=0, **kwargs)
        conn = mavutil.mavlink_connection(f"{ep.scheme}:{ep.address}", **kwargs)
        if ep.scheme.startswith("udp"):
            try:
                conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _UDP_RCVBUF)
            except OSError as err:  # the kernel caps it at net.core.rmem_max; a smaller buffer still works
                log.debug("%s: SO_RCVBUF: %s", self.name, err)
        return conn

    def _close(self) -> None:
        with self._send_lock:
            conn, self._conn = self._conn, None
        self._opened.clear()
        if conn is not None:
            try:
                conn.close()
            except Exception as err:
                log.debug("%s: close: %s", self.name, err)

    def _receive_loop(self) -> None:
        delay = self.cfg.reconnect_initial_s
        while not self._stop.is_set():
            if self._conn is None:
                try:
                    conn = self._open()
                except Exception as err:
                    log.warning("%s: cannot open %s (%s); retrying in %.1f s", self.name, self.endpoint, err, delay)
                    self._stop.wait(delay)
                    delay = min(delay * 2, self.cfg.reconnect_max_s)
                    continue
                with self._send_lock:
                    self._conn = conn
                self._rx = self._new_parser()
                self._opened.set()
                log.info("%s: MAVLink %s open", self.name, self.endpoint)
            try:
                alive = self._read_once(self._conn)
            except Exception as err:
                alive = False
                log.warning("%s: MAVLink %s failed: %s", self.name, self.endpoint, err)
            if not alive:
                self._close()
                self.reconnects += 1
                self._stop.wait(delay)
                delay = min(delay * 2, self.cfg.reconnect_max_s)
            else:
                delay = self.cfg.reconnect_initial_s

    def _read_once(self, conn: mavutil.mavfile) -> bool:
        """Wait briefly for data and dispatch what came; False when the transport is gone."""
        if not conn.select(_POLL_S):
            return True
        scheme = self.endpoint.scheme
        if scheme in ("tcp", "tcpin"):
            data = self._read_stream(conn)
            if data is None:
                return False
        elif scheme.startswith("udp"):
            for _ in range(_UDP_BURST):  # drain what is queued: one select per burst, not per datagram
                data = conn.recv()
                if not data:
                    break
                self._feed(data, scheme)
            return True
        else:
            data = conn.recv(4096)
        if data:
            self._feed(data, scheme)
        return True

    def _feed(self, data: bytes, scheme: str) -> None:
        """Parse received bytes and dispatch the messages in them, timing it (the loop reads nothing meanwhile)."""
        start, cpu = time.perf_counter(), time.thread_time()
        try:
            self._parse_and_dispatch(data, scheme)
        finally:
            took = time.perf_counter() - start
            self.rx_longest_s = max(self.rx_longest_s, took)
            self.rx_longest_cpu_s = max(self.rx_longest_cpu_s, time.thread_time() - cpu)
            self.rx_slow += took > 0.05

    def _parse_and_dispatch(self, data: bytes, scheme: str) -> None:
        self.rx_bytes += len(data)
        if scheme.startswith("udp") and self._rx.buf_len() > 0 and data[0] in _MAGIC:
            # the last datagram left half a packet and this one starts a new packet: the half was truncated.
            # Drop it, or the parser would read this packet as its tail and lose both.
            self._count_bad("truncated packet")
            self._rx = self._new_parser()
        try:
            msgs = self._rx.parse_buffer(bytes(data)) or []
        except Exception as err:  # the parser should not raise with robust parsing, but never let it kill us
            self._count_bad(f"parser error: {err}")
            self._rx = self._new_parser()
            return
        for msg in msgs:
            self._dispatch(msg)

    def _count_bad(self, reason: str) -> None:
        """Count bad input and say so, without flooding the log when a link spews garbage."""
        self.rx_bad += 1
        if self._bad_log.take():  # by time, not by count: a flood's rate must not set the log's
            log.warning("%s: bad MAVLink input on %s (%s); %d bad so far", self.name, self.endpoint, reason,
                        self.rx_bad)

    def _read_stream(self, conn: mavutil.mavfile) -> bytes | None:
        """Read a TCP socket ourselves, because pymavlink cannot tell "no data yet" from "peer gone"."""
        if conn.port is None:  # a TCP server with no client: accept the waiting one
            conn.recv(0)
            self._rx = self._new_parser()
            return b""
        try:
            data = conn.port.recv(4096)
        except BlockingIOError:
            return b""
        except OSError as err:
            data = b""
            log.debug("%s: TCP receive: %s", self.name, err)
        if data:
            return data
        if self.endpoint.scheme == "tcp":
            log.warning("%s: TCP peer %s closed the connection", self.name, self.endpoint.address)
            return None
        log.info("%s: TCP client left %s", self.name, self.endpoint.address)
        with self._send_lock:
            conn.port.close()
            conn.port = None
            conn.fd = conn.listen.fileno()
        return b""

    def _dispatch(self, msg: MAVLinkMessage) -> None:
        """The one place an incoming message is accepted and handed to subscribers (on the receive loop: they
        must only record or queue, never wait)."""
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self._count_bad(getattr(msg, "reason", "bad data"))
            return
        if mtype.startswith("UNKNOWN_"):  # a message id this dialect lacks (or noise that looked like one)
            self.rx_unknown += 1
            return
        self.rx_messages += 1
        handled = any(types is None or mtype in types for _, types in self._subs)  # something here acts on it
        if not self.signing.admit(msg, self.send, (self.system_id, self.component_id), self._refused, handled):
            return
        if mtype == "HEARTBEAT" and is_autopilot_heartbeat(msg):
            self._autopilot_heartbeat(msg)
        for callback, types in self._subs:
            if types is not None and mtype not in types:
                continue
            try:
                callback(msg)
            except Exception:
                log.exception("%s: subscriber %r failed on %s", self.name, callback, mtype)

    def _refused(self, msg: MAVLinkMessage, reason: str) -> None:
        for callback in list(self._refused_cbs):
            try:
                callback(msg, reason)
            except Exception:
                log.exception("%s: refusal callback failed", self.name)

    def _autopilot_heartbeat(self, msg: MAVLinkMessage) -> bool:
        """Settle the autopilot (and, unless configured, our system id) once, from the first autopilot heartbeat;
        with a key, a first one that was unsigned is provisional until a signed one arrives. False: a stranger's
        heartbeat (subscribers still see it; telemetry takes only the autopilot's)."""
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src[0] == 255:
            return False
        signed = bool(getattr(msg, "_signed", False))
        if self.autopilot is None or (src != self.autopilot and signed and not self._autopilot_signed):
            self._adopt_autopilot(src, signed)
        elif src != self.autopilot:
            self.foreign_autopilot_heartbeats += 1
            if self.foreign_autopilot_heartbeats == 1:
                log.warning("%s: autopilot heartbeat from %d/%d ignored: the autopilot is %d/%d", self.name, *src,
                            *self.autopilot)
            return False
        elif signed and not self._autopilot_signed:
            self._autopilot_signed = True
        self.last_autopilot_heartbeat = msg
        self._heard.put(self.clock())  # the timer thread says "found", not this one (see _watch_autopilot)
        return True

    def _adopt_autopilot(self, src: tuple[int, int], signed: bool) -> None:
        if self.autopilot is not None:
            log.warning("%s: autopilot %d/%d signs: it replaces %d/%d, whose heartbeat was unsigned", self.name,
                        *src, *self.autopilot)
        self.autopilot = src
        self._autopilot_signed = signed
        self.signing.protect(src)
        if self._configured_system is None and self.system_id != src[0]:
            log.info("%s: vehicle is system %d", self.name, src[0])
            with self._send_lock:
                self.system_id = src[0]
                self._tx.srcSystem = src[0]

    def _notify(self, alive: bool) -> None:
        for callback in list(self._autopilot_cbs):
            try:
                callback(alive)
            except Exception:
                log.exception("%s: autopilot callback failed", self.name)

    def _timer_loop(self) -> None:
        next_beat = self.clock()
        while not self._stop.is_set():
            self._watch_autopilot()
            if not self._send_heartbeat:
                continue
            now = self.clock()
            if now >= next_beat:
                next_beat = next_heartbeat(next_beat, now)
                if self._is_healthy():
                    self.send(self.heartbeat_message())

    def _watch_autopilot(self) -> None:
        """Wait up to a poll for heartbeats the receive thread heard, then declare the autopilot found or lost.

        Only this thread writes ``autopilot_alive`` and calls the on_autopilot callbacks: a heartbeat heard while a
        loss is being declared is taken on the next pass and reported as found after the loss, never lost after
        it (with two writers, a late "lost" could overwrite it and stay until the next loss).
        """
        heard = None
        try:
            heard = self._heard.get(timeout=_POLL_S)
            while True:
                heard = self._heard.get_nowait()
        except queue.Empty:
            pass
        if heard is not None:
            self._last_autopilot_seen = heard
            if not self.autopilot_alive:
                self.autopilot_alive = True
                self._found.set()
                log.info("%s: autopilot %d/%d found", self.name, *(self.autopilot or (0, 0)))
                self._notify(True)
            return
        seen = self._last_autopilot_seen
        now = self.clock()
        if self.autopilot_alive and seen is not None and now - seen > self.cfg.heartbeat_timeout_s:
            self.autopilot_alive = False
            self._found.clear()
            log.warning("%s: autopilot heartbeat lost (%.1f s)", self.name, now - seen)
            self._notify(False)

    def _is_healthy(self) -> bool:
        check = self.healthy
        if check is None:
            return True
        try:
            return bool(check())
        except Exception:
            log.exception("%s: health check failed", self.name)
            return False

    def heartbeat_message(self) -> MAVLinkMessage:
        """Our heartbeat: a camera-type component (or what ``mav_type`` says) with no autopilot."""
        return mavlink2.MAVLink_heartbeat_message(
            self.mav_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3
        )

