"""The one MAVLink connection of the companion: a receive thread, a writer thread, a 1 Hz heartbeat, pub/sub.

Everything MAVLink in the process goes through one ``MavLink``: other parts subscribe to the message types they
care about and ``send`` pymavlink message objects, which the link packs as MAVLink 2 with *its* system and
component id and sequence number. Opening, reconnecting (TCP and serial, with back-off) and reading happen on the
receive thread, which only parses and dispatches (``_dispatch``, the one place incoming messages are accepted);
every outgoing message is packed once (``_pack``, the one place) and written on the writer thread
(``packet_writer``); sending before a peer is known writes 0 bytes. Which peer is the autopilot, and whether it is
alive, is ``autopilot_watch``'s to say; the connection string and the transport are ``endpoint``'s.

pymavlink's ``mavutil`` opens the transports; packing and parsing use the MAVLink 2 ``ardupilotmega`` dialect
directly, so the wire version never depends on the environment or on which module imported pymavlink first.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vehicle.link.autopilot_signing import probe_message
from vehicle.link.autopilot_watch import AutopilotWatch, Source, is_autopilot_heartbeat
from vehicle.link.endpoint import has_peer, open_transport, parse_connection
from vehicle.link.packet_writer import PacketWriter
from vehicle.link.signing import LinkSigning
from vehicle.link.warning_bucket import WarningBucket
from vehicle.settings import MavlinkConfig

log = logging.getLogger(__name__)

MAV_TYPE_CAMERA = mavlink2.MAV_TYPE_CAMERA
MAVLinkMessage = mavlink2.MAVLink_message

_POLL_S = 0.1
_MAGIC = (mavlink2.PROTOCOL_MARKER_V2, mavlink2.PROTOCOL_MARKER_V1)
_UDP_BURST = 64
BAD_LOG_S = 10.0
"""At most one log line per this many seconds about bad input (the count is in ``rx_bad``)."""
HEARTBEAT_PERIOD_S = 1.0


def next_heartbeat(due: float, now: float, period: float = HEARTBEAT_PERIOD_S) -> float:
    """When the heartbeat after the one due at ``due`` (sent at ``now``) is due: on a fixed grid, so that waking up
    to a poll late does not push every later beat back (it gave 0.95 Hz); after a stall of more than a period, a
    new grid from now, with no burst of beats to catch up."""
    due += period
    return due if due > now else now + period


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
        self.watch = AutopilotWatch(name=name, clock=clock, timeout_s=cfg.heartbeat_timeout_s,
                                    on_adopt=self._adopt_autopilot)
        self._conn: mavutil.mavfile | None = None
        self._tx = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=self.component_id)
        self.signing = LinkSigning.from_settings(cfg, name=name)
        self.signing.watch.clock = clock
        self.signing.refusal_log.clock = clock
        self.signing.watch.window_s = max(cfg.heartbeat_timeout_s, 1.0)  # a signed heartbeat comes at 1 Hz
        self._rx = self._new_parser()
        self._send_lock = threading.Lock()
        self._writer: PacketWriter[MAVLinkMessage | bytes] = PacketWriter(self._write, f"{name}-mavlink-tx")
        self._subs_lock = threading.Lock()
        self._subs: list[tuple[Callable[[MAVLinkMessage], None], frozenset[str] | None]] = []
        self._refused_cbs: list[Callable[[MAVLinkMessage, str], None]] = []
        self._stop = threading.Event()
        self._opened = threading.Event()
        self._threads: list[threading.Thread] = []

    # ----------------------------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Start the receive and heartbeat threads; returns at once (the connection opens on the thread)."""
        if self._threads:
            return
        self._stop.clear()
        self._writer.start()
        self._threads = [
            threading.Thread(target=self._receive_loop, name=f"{self.name}-mavlink-rx", daemon=True),
            threading.Thread(target=self._timer_loop, name=f"{self.name}-mavlink-hb", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop the threads (the writer first sends what was handed to it) and close the connection; safe to
        call twice."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._writer.stop()
        self._threads = []
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
        return self.watch.wait_found(timeout)

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
        self.watch.on_change(callback)

    def on_signing_change(self, callback: Callable[[str, int], None]) -> None:
        """``callback(text, severity)`` on the timer thread when the autopilot's signing verdict changes (how it signs,
        whether it answers us; a bad first verdict too): text for one STATUSTEXT (vehicle/link/autopilot_signing.py)."""
        self.signing.watch.on_change(callback)

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
        return self._writer.send(msg)

    def send_raw(self, packet: bytes) -> int:
        """Write an already packed MAVLink packet unchanged (log replay keeps the recorded ids and sequence)."""
        return self._writer.send(bytes(packet))

    @property
    def connected(self) -> bool:
        conn = self._conn
        return conn is not None and has_peer(self.endpoint, conn)

    @property
    def autopilot(self) -> Source | None:
        """The autopilot's (system, component), settled by its first heartbeat; None until then."""
        return self.watch.autopilot

    @property
    def autopilot_alive(self) -> bool:
        return self.watch.alive

    @property
    def last_autopilot_heartbeat(self) -> MAVLinkMessage | None:
        return self.watch.last_heartbeat

    @property
    def foreign_autopilot_heartbeats(self) -> int:
        """Autopilot heartbeats from a stranger: ignored (the identity is settled once)."""
        return self.watch.foreign_heartbeats

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
    def _write(self, item: MAVLinkMessage | bytes) -> int:
        """Pack (unless raw) and write one packet; the bytes written."""
        with self._send_lock:
            conn = self._conn
            if conn is None or not has_peer(self.endpoint, conn):
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
        self.signing.watch.outgoing(msg, self._asked_autopilot())
        self._tx.seq = (self._tx.seq + 1) % 256
        self._tx.total_packets_sent += 1
        self._tx.total_bytes_sent += len(buf)
        return buf

    @staticmethod
    def _new_parser() -> mavlink2.MAVLink:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        return parser

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
                    conn = open_transport(self.endpoint, self.system_id, self.component_id, self.name)
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
        if self.endpoint.is_tcp:
            data = self._read_stream(conn)
            if data is None:
                return False
        elif self.endpoint.is_udp:
            for _ in range(_UDP_BURST):  # drain what is queued: one select per burst, not per datagram
                data = conn.recv()
                if not data:
                    break
                self._feed(data, getattr(conn, "last_peer", None))
            return True
        else:
            data = conn.recv(4096)
        if data:
            self._feed(data)
        return True

    def _feed(self, data: bytes, peer: tuple[str, int] | None = None) -> None:
        """Parse received bytes and dispatch the messages in them, timing it (the loop reads nothing meanwhile).
        ``peer``: the UDP address they came from, kept on each message as ``_peer`` (ids are free, addresses
        less so: a reader may follow a source only from where it first heard it)."""
        start, cpu = time.perf_counter(), time.thread_time()
        try:
            self._parse_and_dispatch(data, peer)
        finally:
            took = time.perf_counter() - start
            self.rx_longest_s = max(self.rx_longest_s, took)
            self.rx_longest_cpu_s = max(self.rx_longest_cpu_s, time.thread_time() - cpu)
            self.rx_slow += took > 0.05

    def _parse_and_dispatch(self, data: bytes, peer: tuple[str, int] | None = None) -> None:
        self.rx_bytes += len(data)
        if self.endpoint.is_udp and self._rx.buf_len() > 0 and data[0] in _MAGIC:
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
            msg._peer = peer
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
            self.watch.heard(msg)
        elif mtype == "COMMAND_ACK":
            self.signing.watch.incoming_ack(msg, self._asked_autopilot(), (self.system_id, self.component_id))
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

    def _adopt_autopilot(self, src: Source) -> None:
        """The autopilot is settled (or replaced by one that signs): protect its identity, and take its system id
        as ours unless one was configured."""
        self.signing.protect(src)
        if self._configured_system is None and self.system_id != src[0]:
            log.info("%s: vehicle is system %d", self.name, src[0])
            with self._send_lock:
                self.system_id = src[0]
                self._tx.srcSystem = src[0]

    def _asked_autopilot(self) -> Source | None:
        """The autopilot, or before one is settled (an unsigned one beside our key) the last that claimed to be it."""
        return self.watch.autopilot or self.signing.claimed

    def _probe_autopilot(self) -> bool:
        """Ask the autopilot whether it answers us (False: nobody to ask yet)."""
        target = self._asked_autopilot()
        if target is not None:
            self.send(probe_message(target))
        return target is not None

    def _timer_loop(self) -> None:
        next_beat = self.clock()
        while not self._stop.is_set():
            self.watch.watch(_POLL_S)
            self.signing.watch.judge(self._probe_autopilot)
            self.signing.refusal_log.flush()
            if not self._send_heartbeat:
                continue
            now = self.clock()
            if now >= next_beat:
                next_beat = next_heartbeat(next_beat, now)
                if self._is_healthy():
                    self.send(self.heartbeat_message())

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

