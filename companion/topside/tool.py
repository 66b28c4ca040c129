"""The surface tool's one MAVLink connection and its receive loop: the link role.

One owner of the connection: this loop reads every message, keeps the link and companion status, finds the
companion, and hands each of its messages to the role that owns it: ``push_pairing`` (captures and pushed
thumbnails), ``gallery_sync`` (index.json, status lines, FTP fallback and checks), ``page_state`` (what the page
shows) and ``actions`` (what the page asks for). They share one explicit ``surface_state.SurfaceContext``.

With a signing key, everything the companion sends changes the gallery, the dive or the page, so only messages
whose signature the connection verified (``vehicle.link.signing.LinkSigning``, the companion's own check: valid
signature, fresh timestamp per stream) are acted on; anything else is ignored, counted per source, and reported
once per source on the page. The companion's identity is then settled by its first signed messages (or
``--companion``) and never re-learned.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import OrderedDict, deque
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig
from companion.topside.actions import SurfaceActions
from companion.topside.boot_clock import BootClock
from companion.topside.ftp_client import FtpClient
from companion.topside.gallery import Gallery
from companion.topside.gallery_sync import GallerySync
from companion.topside.page_state import PageState
from companion.topside.push_pairing import PushPairing
from companion.topside.surface_state import (
    DEPTH_VALUE,
    FULL_FRAME_TIMEOUT_S,
    MARKS_TIMEOUT_S,
    OFFLINE_EVERY_S,
    PUSH_MARKER,
    SEVERITY_WARNING,
    LinkStatus,
    SurfaceContext,
    SurfaceOptions,
)
from vehicle.link.autopilot_watch import is_autopilot_heartbeat
from vehicle.link.connection import MavLink
from vehicle.link.signing import MAX_SOURCES, OTHER_SOURCES

__all__ = ["LinkStatus", "SurfaceOptions", "SurfaceTool"]

log = logging.getLogger("merlion.surface")

MAV_TYPE_CAMERA = mav.MAV_TYPE_CAMERA
MAV_TYPE_GCS = mav.MAV_TYPE_GCS
INBOX_MAX = 4096
"""Messages waiting for the receive loop. The link's thread only parses; when the loop is held up (a slow disk, a
flood) a longer queue would only grow memory without bound: past this, messages are dropped and counted, as the
socket would drop them (what matters is re-sent or re-read: captures, index.json, FTP)."""
HANDLE_AT_ONCE = 256
"""Messages handled before the loop's housekeeping runs again (FTP retries, expiries, the page's requests): a
flood cannot starve them."""
MAX_VALUES = 64
"""Value names kept (the companion sends a handful); a sender making up new names is ignored past this."""
EARLY_TEXT_SOURCES = 16
"""Sources whose status lines are kept before the companion is known (the newest sources)."""
MAX_CAMERAS = 16
"""Camera components remembered (by heartbeat) until the companion is known: the ones heard most recently (a real
one beats at 1 Hz). Each made-up id was a row for the whole run, 65,536 possible."""


def verified(msg) -> bool:
    """Whether the connection's ``LinkSigning`` checked ``msg``'s signature and timestamp and found them good (it
    marks such a message; an unsigned read it let through, or a badly signed one, carries no mark)."""
    return bool(getattr(msg, "_signed", False))


class SurfaceTool:
    """Receive loop and dispatch to the roles. ``run`` blocks until ``stop`` is set."""

    def __init__(self, options: SurfaceOptions, gallery: Gallery, clock=time.monotonic) -> None:
        """Checks the connection string at once (a typo is a one-line error); nothing opens until ``open``."""
        self._link = MavLink(
            options.connect,
            MavlinkConfig(connection=options.connect, system_id=options.system_id,
                          component_id=options.component_id, signing_key_file=options.signing_key_file),
            name="surface", mav_type=MAV_TYPE_GCS,
        )
        gallery.defer_writes(options.gallery_write_every_s)  # flushed by housekeeping, and when the run ends
        self.ctx = SurfaceContext(options=options, gallery=gallery, clock=clock, send=self._link.send)
        self.ctx.status.statustext = deque(maxlen=options.statustext_keep)
        self.sync = GallerySync(self.ctx)
        self.pairing = PushPairing(self.ctx, self.sync)
        self.page = PageState(self.ctx)
        self.actions = SurfaceActions(self.ctx)
        self._inbox: queue.Queue = queue.Queue(maxsize=INBOX_MAX)
        self._opened = False
        self._early_text: dict[tuple[int, int], deque] = {}
        self._last_seq: dict[tuple[int, int], int] = {}
        self._seq_peer: dict[tuple[int, int], tuple[str, int] | None] = {}
        """The address each followed source's sequence numbers are read from (two rows at most)."""
        self._cameras: OrderedDict[tuple[int, int], None] = OrderedDict()
        """Camera components heard (by heartbeat), most recent last; only until the companion is known."""
        self._offline_at = -1e9
        self._signed_only = self._link.signing.enabled
        self._boot_clock = BootClock()  # the companion's time_boot_ms on this clock: the depth track's times

    # the context's parts, as other code and tests name them
    options = property(lambda self: self.ctx.options)
    gallery = property(lambda self: self.ctx.gallery)
    status = property(lambda self: self.ctx.status)
    lock = property(lambda self: self.ctx.lock)
    marks = property(lambda self: self.ctx.marks)
    images = property(lambda self: self.pairing.images)

    # --- connection ----------------------------------------------------------------------------------------

    def open(self, timeout: float = 5.0) -> None:
        """Open the link (its own receive thread feeds our inbox; it also sends our 1 Hz GCS heartbeat)."""
        if self._opened:
            return
        self._opened = True
        self._link.subscribe(self._receive)
        self._link.start()
        self._link.wait_open(timeout)

    def close(self) -> None:
        self._link.stop()

    def run(self, stop: threading.Event, duration: float | None = None) -> None:
        """The loop: handle what arrived, then housekeeping; returns when stopped or after ``duration``."""
        self.open()
        clock = self.ctx.clock
        end = None if duration is None else clock() + duration
        try:
            while not stop.is_set() and (end is None or clock() < end):
                try:
                    msg = self._inbox.get(timeout=0.05)
                except queue.Empty:
                    msg = None
                handled = 0
                while msg is not None:
                    self.handle(msg)
                    handled += 1
                    try:
                        msg = self._inbox.get_nowait() if handled < HANDLE_AT_ONCE else None
                    except queue.Empty:
                        msg = None
                self.housekeeping()
        finally:
            self.close()
            self.gallery.flush()
            self.write_offline_page()

    def _receive(self, msg) -> None:
        """On the link's receive thread: queue for the loop, or drop when the queue is full."""
        try:
            self._inbox.put_nowait(msg)
        except queue.Full:
            with self.ctx.lock:
                self.ctx.status.inbox_dropped += 1
                first = self.ctx.status.inbox_dropped == 1
            if first:
                log.warning("the receive loop is %d messages behind: dropping what arrives until it catches up",
                            INBOX_MAX)

    def housekeeping(self) -> None:
        now = self.ctx.clock()
        while True:
            try:
                self.ctx.requests.get_nowait()()
            except queue.Empty:
                break
        if now - self._offline_at >= OFFLINE_EVERY_S:
            self._offline_at = now
            self.write_offline_page()
        self.gallery.flush_due()
        if self.ctx.ftp is not None:
            self.ctx.ftp.tick()
        self.pairing.expire(now)
        self.sync.pull_index_when_due(now)

    # --- dispatch ------------------------------------------------------------------------------------------

    def handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if self._signed_only and not verified(msg):
            self._ignore(msg, source)
            return
        now = time.time()
        status = self.ctx.status
        with self.ctx.lock:
            status.messages += 1
            status.last_message = now
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, source, now)
            self._count_lost(source, msg)
            return
        if kind == "CAMERA_IMAGE_CAPTURED":
            self._adopt(source)
        elif kind in ("DATA_TRANSMISSION_HANDSHAKE", "STATUSTEXT", "NAMED_VALUE_FLOAT") and source in self._cameras:
            self._adopt(source)
        self._count_lost(source, msg)
        if status.companion is None and kind == "STATUSTEXT":
            # the companion's first lines ("started") may come before its heartbeat: keep a few for later
            early = self._early_text.pop(source, None) or deque(maxlen=5)
            early.append((msg, now))
            self._early_text[source] = early  # newest source last: the oldest goes past EARLY_TEXT_SOURCES
            while len(self._early_text) > EARLY_TEXT_SOURCES:
                del self._early_text[next(iter(self._early_text))]
        if status.companion is None or source != status.companion:
            return
        if kind == "CAMERA_IMAGE_CAPTURED":
            self.pairing.on_capture(msg)
        elif kind == "DATA_TRANSMISSION_HANDSHAKE":
            self.pairing.on_handshake(msg)
        elif kind == "ENCAPSULATED_DATA":
            self.pairing.on_data(msg)
        elif kind == "STATUSTEXT":
            self.sync.on_statustext(msg, now)
        elif kind in ("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT"):
            self._on_value(msg, kind, now)
        elif kind == "FILE_TRANSFER_PROTOCOL" and self.ctx.ftp is not None:
            self.ctx.ftp.handle(msg)

    def _count_lost(self, source: tuple[int, int], msg) -> None:
        """``lost_packets``: the gaps in the sequence numbers of the vehicle's own sources only (the autopilot and
        the companion, once known). Sender ids are free, so following every source heard let a stranger grow the
        table to 65,536 rows and add up to 127 made-up losses per message; the table now has two rows at most.

        Without a key the vehicle's own ids are free too: each source is followed only from the UDP address its
        first counted message came from (the one that made it the autopilot or the companion), never re-learnt; a
        message under its ids from another address is counted in ``other_address_messages`` instead (a device
        sending under them with made-up numbers added up to 127 "lost" packets a message). With a key only
        verified messages get here, wherever they come from."""
        status = self.ctx.status
        if source != status.companion and source != status.autopilot:
            return
        peer = getattr(msg, "_peer", None)
        with self.ctx.lock:
            if not self._signed_only and self._seq_peer.setdefault(source, peer) != peer:
                status.other_address_messages += 1
                return
            seq = msg.get_seq()
            last = self._last_seq.get(source)
            gap = 0 if last is None else (seq - last - 1) % 256
            if gap < 128:  # a larger jump is a restart or reordering, not a loss
                status.lost_packets += gap
            self._last_seq[source] = seq

    def _ignore(self, msg, source: tuple[int, int]) -> None:
        """An unsigned (or badly signed, or replayed) message on a signed link: counted, reported once per source
        (a table of bounded size: spoofed ids by the thousand are counted together under 0/0)."""
        status = self.ctx.status
        with self.ctx.lock:
            status.unsigned_ignored += 1
            key = source if source in status.unsigned_sources or len(status.unsigned_sources) < MAX_SOURCES \
                else OTHER_SOURCES
            count = status.unsigned_sources.get(key, 0) + 1
            status.unsigned_sources[key] = count
            if count == 1:
                text = f"unsigned {msg.get_type()} from {key[0]}/{key[1]} ignored (and any more from it)"
                status.warnings.append({"time": time.time(), "severity": SEVERITY_WARNING, "text": text})
        if count == 1:
            log.warning("%s", text)

    def _on_value(self, msg, kind: str, now: float) -> None:
        name = msg.name.decode("ascii", "replace") if isinstance(msg.name, bytes) else msg.name
        name = name.rstrip("\0")
        if kind == "NAMED_VALUE_INT" and name == PUSH_MARKER:
            self.pairing.on_marker(int(msg.value))
            return
        measured = self._boot_clock.local(int(msg.time_boot_ms), now)  # not its arrival: see boot_clock
        with self.ctx.lock:
            status = self.ctx.status
            if name not in status.values and len(status.values) >= MAX_VALUES:
                status.values_dropped += 1
                return
            status.values[name] = float(msg.value)
            status.values_at = now
            if name == DEPTH_VALUE and math.isfinite(float(msg.value)):
                status.depth_track.append((round(measured, 2), round(float(msg.value), 2)))

    def _on_heartbeat(self, msg, source: tuple[int, int], now: float) -> None:
        status = self.ctx.status
        with self.ctx.lock:
            if msg.type == MAV_TYPE_CAMERA:
                if status.companion is None:
                    self._cameras[source] = None
                    self._cameras.move_to_end(source)
                    if len(self._cameras) > MAX_CAMERAS:
                        self._cameras.popitem(last=False)
                if source == status.companion:
                    status.companion_heartbeat = now
            elif is_autopilot_heartbeat(msg) and source[0] != 255:
                # the first autopilot is the vehicle's (as the link's AutopilotWatch settles it): a stranger's
                # heartbeat neither replaces it on the page nor keeps a lost one looking alive
                status.autopilot = status.autopilot or source
                if source == status.autopilot:
                    status.autopilot_heartbeat = now
                else:
                    status.foreign_autopilot_heartbeats += 1
        if self.ctx.options.companion == source:
            self._adopt(source)

    def _adopt(self, source: tuple[int, int]) -> None:
        """Lock onto the companion: the configured one, else the first camera (by heartbeat) that sends captures,
        images, status lines or values (a plain camera, such as BlueOS's camera manager, sends none of those)."""
        ctx = self.ctx
        if ctx.status.companion is not None:
            return
        if ctx.options.companion is not None and source != ctx.options.companion:
            return
        log.info("companion found at system %d component %d", *source)
        with ctx.lock:
            ctx.status.companion = source
            ctx.status.companion_heartbeat = time.time()
        for msg, when in self._early_text.pop(source, ()):
            self.sync.on_statustext(msg, when)
        self._early_text.clear()
        self._cameras.clear()  # only needed to find the companion
        if ctx.options.ftp:
            ctx.ftp = FtpClient(self._send_ftp, source, own=(ctx.options.system_id, ctx.options.component_id),
                                clock=ctx.clock)
            ctx.pairing.index_due = ctx.clock()  # learn the summary as it stands now

    def _send_ftp(self, system: int, component: int, payload: bytes) -> None:
        self._link.send(mav.MAVLink_file_transfer_protocol_message(0, system, component, list(payload)))

    # --- what the page reads and asks for (its threads) ----------------------------------------------------

    def full_frame(self, index: int, timeout: float = FULL_FRAME_TIMEOUT_S) -> Path | None:
        return self.actions.full_frame(index, timeout)

    def mark(self, index: int, kind: str, timeout: float = MARKS_TIMEOUT_S) -> str:
        return self.actions.mark(index, kind, timeout)

    def send_marks(self, like: list[int], unlike: list[int], timeout: float = MARKS_TIMEOUT_S) -> str:
        return self.actions.send_marks(like, unlike, timeout)

    def write_offline_page(self) -> None:
        self.page.write_offline_page()

    def snapshot(self) -> dict:
        return self.page.snapshot()
