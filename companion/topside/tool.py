"""The surface tool's one MAVLink connection and its receive loop.

One owner of the connection: this loop reads every message, keeps the link and companion status, pairs each
CAMERA_IMAGE_CAPTURED with the thumbnail pushed for it (DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA), and
falls back to a MAVLink FTP pull (``/summary/<n>.jpg``) for every capture whose push was lost or never came. It
pulls ``/summary/index.json`` when it first meets the companion and after the summary changed, which gives the
score and heading of each frame and mirrors the summary even when a STATUSTEXT was lost.

Pairing pushes with captures: the image protocol carries no image index, so our companion sends a
NAMED_VALUE_INT ``MRL_PUSH`` = image index right before each handshake, and that handshake belongs to that frame.
Without a marker (another sender, or the marker lost) pushes are paired with captures in the order both arrive
(the companion announces a frame, then pushes its thumbnail; thumbnails of frames trimmed before they were sent
are dropped, and the trim is announced first): each handshake takes the oldest capture still waiting. An image
whose packets never all arrive is fetched by FTP instead.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig
from companion.topside.boot_clock import BootClock
from companion.topside.ftp_client import FtpClient, crc32_mavftp
from companion.topside.gallery import Capture, Gallery
from companion.topside.messages import (
    capture_from_message,
    index_dive,
    index_topics,
    mftp_path,
    parse_index,
    parse_statustext,
)
from companion.topside.offline_page import write_offline_page
from vehicle.link.connection import MavLink, is_autopilot_heartbeat
from vehicle.protocol.image_push import Abandoned, ImageReceiver, LostHandshake, PushedImage

log = logging.getLogger("merlion.surface")

MAV_TYPE_CAMERA = mav.MAV_TYPE_CAMERA
MAV_TYPE_GCS = mav.MAV_TYPE_GCS
INDEX_PATH = "/summary/index.json"
PUSH_MARKER = "MRL_PUSH"
DEPTH_VALUE = "MRL_DEPTH"
SEVERITY_WARNING = 4
FULL_FRAME_TIMEOUT_S = 120.0
MARKS_TIMEOUT_S = 30.0
"""A marks upload is a few hundred bytes: a page's request waits this long for the companion's answer."""
"""A full frame (tens of kB) at a 2,000 B/s budget, sent after everything else: give it time."""
OFFLINE_EVERY_S = 2.0


@dataclass
class SurfaceOptions:
    connect: str = "udpin:0.0.0.0:14550"
    system_id: int = 254
    """Not 255: ArduSub takes heartbeats of system 255 for the pilot's GCS and would hide a real GCS loss."""
    component_id: int = 190
    companion: tuple[int, int] | None = None
    """(system, component) of the companion; None: the camera component that sends captures or pushes images."""
    push_timeout_s: float = 30.0
    """A capture with no pushed thumbnail after this long is fetched by FTP."""
    push_stall_s: float = 3.0
    """A push that received nothing for this long (longer on a slow link) is given up: the rest comes by FTP."""
    index_refresh_s: float = 10.0
    """Pull index.json at most this often, and only after the summary changed."""
    ftp: bool = True
    statustext_keep: int = 20
    signing_key_file: str | None = None


@dataclass
class LinkStatus:
    """What the web page shows about the link and the companion."""

    started: float = field(default_factory=time.time)
    messages: int = 0
    last_message: float | None = None
    companion: tuple[int, int] | None = None
    companion_heartbeat: float | None = None
    autopilot: tuple[int, int] | None = None
    autopilot_heartbeat: float | None = None
    values: dict[str, float] = field(default_factory=dict)
    values_at: float | None = None
    statustext: deque = field(default_factory=lambda: deque(maxlen=20))
    warnings: deque = field(default_factory=lambda: deque(maxlen=20))
    """Status lines of severity WARNING or worse, kept apart: summary churn never pushes them out."""
    depth_track: deque = field(default_factory=lambda: deque(maxlen=7200))
    """(surface time, depth m) from the companion's 1 Hz MRL_DEPTH: the page's depth-over-time plot."""
    pushed_ok: int = 0
    pushed_lost: int = 0
    ftp_ok: int = 0
    ftp_failed: int = 0
    index_pulls: int = 0
    verified: int = 0
    """Pushed (or part-pushed) thumbnails whose CRC matched the companion's file."""
    mismatched: int = 0
    lost_packets: int = 0


class SurfaceTool:
    """Receive loop, pairing of pushes with captures, FTP fallback. ``run`` blocks until ``stop`` is set."""

    def __init__(self, options: SurfaceOptions, gallery: Gallery, clock=time.monotonic) -> None:
        """Checks the connection string at once (a typo is a one-line error); nothing opens until ``open``."""
        self.options = options
        self.gallery = gallery
        self._clock = clock
        self.status = LinkStatus()
        self.status.statustext = deque(maxlen=options.statustext_keep)
        self.lock = threading.Lock()
        self.images = ImageReceiver(clock=clock)
        self._inbox: queue.Queue = queue.Queue()
        self._link = MavLink(
            options.connect,
            MavlinkConfig(connection=options.connect, system_id=options.system_id,
                          component_id=options.component_id, signing_key_file=options.signing_key_file),
            name="surface", mav_type=MAV_TYPE_GCS,
        )
        self._opened = False
        self._last_announced: int | None = None
        self._early_text: dict[tuple[int, int], deque] = {}
        self._last_seq: dict[tuple[int, int], int] = {}
        self._ftp: FtpClient | None = None
        self._cameras: set[tuple[int, int]] = set()
        self._waiting: deque[tuple[int, float]] = deque()  # captures waiting for a push: (image index, since)
        self._early: deque[int] = deque(maxlen=16)  # handshakes that came before their capture (their numbers)
        self._expected: dict[int, int] = {}  # thumbnail bytes by image index, from index.json (JPEG only)
        self._bound: dict[int, int] = {}  # handshake number -> image index
        self._orphans: dict[int, PushedImage] = {}  # finished pushes not yet paired
        self._lost_push: dict[int, Abandoned] = {}  # pushes abandoned before pairing, by handshake number
        self._fetching: set[tuple[str | None, int]] = set()  # (dive, image index) being pulled by FTP
        self._marker: int | None = None  # image index named by the last MRL_PUSH, until its handshake comes
        self._crc: dict[int, int] = {}  # thumbnail CRC32 by image index, from index.json (JPEG only)
        self._unverified: dict[int, bytes] = {}  # pushed thumbnails waiting for an index.json with their CRC
        self._index_due: float | None = None
        self._index_pulled_at = -1e9
        self.marks: dict[str, list[int]] = {"like": [], "unlike": []}
        """The marks this tool last had accepted by the companion (the page shows them on the cards)."""
        self._requests: queue.Queue = queue.Queue()  # work handed to the receive loop by other threads (web)
        self._offline_at = -1e9
        self._boot_clock = BootClock()  # the companion's time_boot_ms on this clock: the depth track's times

    # --- connection ----------------------------------------------------------------------------------------

    def open(self, timeout: float = 5.0) -> None:
        """Open the link (its own receive thread feeds our inbox; it also sends our 1 Hz GCS heartbeat)."""
        if self._opened:
            return
        self._opened = True
        self._link.subscribe(self._inbox.put)
        self._link.start()
        self._link.wait_open(timeout)

    def close(self) -> None:
        self._link.stop()

    def run(self, stop: threading.Event, duration: float | None = None) -> None:
        """The loop: handle what arrived, then housekeeping; returns when stopped or after ``duration``."""
        self.open()
        end = None if duration is None else self._clock() + duration
        try:
            while not stop.is_set() and (end is None or self._clock() < end):
                try:
                    msg = self._inbox.get(timeout=0.05)
                except queue.Empty:
                    msg = None
                while msg is not None:
                    self.handle(msg)
                    try:
                        msg = self._inbox.get_nowait()
                    except queue.Empty:
                        msg = None
                self.housekeeping()
        finally:
            self.close()
            self.write_offline_page()

    def housekeeping(self) -> None:
        now = self._clock()
        while True:
            try:
                self._requests.get_nowait()()
            except queue.Empty:
                break
        if now - self._offline_at >= OFFLINE_EVERY_S:
            self._offline_at = now
            self.write_offline_page()
        if self._ftp is not None:
            self._ftp.tick()
        for stalled in self.images.expire(self.options.push_stall_s):
            self._on_push_result(stalled)
        while self._waiting and now - self._waiting[0][1] > self.options.push_timeout_s:
            index, _ = self._waiting.popleft()
            log.info("no push for capture %d after %.0f s: fetching it by FTP", index, self.options.push_timeout_s)
            self._fetch_thumbnail(index)
        if self._index_due is not None and now >= self._index_due and self._ftp is not None:
            if INDEX_PATH not in self._ftp.pending():
                self._index_due = None
                self._index_pulled_at = now
                self._ftp.fetch(INDEX_PATH, self._on_index)

    # --- dispatch ------------------------------------------------------------------------------------------

    def handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        now = time.time()
        seq = msg.get_seq()
        with self.lock:
            self.status.messages += 1
            self.status.last_message = now
            last = self._last_seq.get(source)
            gap = 0 if last is None else (seq - last - 1) % 256
            if gap < 128:  # a larger jump is a restart or reordering, not a loss
                self.status.lost_packets += gap
            self._last_seq[source] = seq
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, source, now)
            return
        if kind == "CAMERA_IMAGE_CAPTURED":
            self._adopt(source)
        elif kind in ("DATA_TRANSMISSION_HANDSHAKE", "STATUSTEXT", "NAMED_VALUE_FLOAT") and source in self._cameras:
            self._adopt(source)
        if self.status.companion is None and kind == "STATUSTEXT":
            # the companion's first lines ("started") may come before its heartbeat: keep a few for later
            self._early_text.setdefault(source, deque(maxlen=5)).append((msg, now))
        if self.status.companion is None or source != self.status.companion:
            return
        if kind == "CAMERA_IMAGE_CAPTURED":
            self._on_capture(msg)
        elif kind == "DATA_TRANSMISSION_HANDSHAKE":
            self._on_handshake(msg)
        elif kind == "ENCAPSULATED_DATA":
            self._on_push_result(self.images.handle(msg))
        elif kind == "STATUSTEXT":
            self._on_statustext(msg, now)
        elif kind in ("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT"):
            name = msg.name.decode("ascii", "replace") if isinstance(msg.name, bytes) else msg.name
            name = name.rstrip("\0")
            if kind == "NAMED_VALUE_INT" and name == PUSH_MARKER:
                self._marker = int(msg.value)
                return
            measured = self._boot_clock.local(int(msg.time_boot_ms), now)  # not its arrival: see boot_clock
            with self.lock:
                self.status.values[name] = float(msg.value)
                self.status.values_at = now
                if name == DEPTH_VALUE and math.isfinite(float(msg.value)):
                    self.status.depth_track.append((round(measured, 2), round(float(msg.value), 2)))
        elif kind == "FILE_TRANSFER_PROTOCOL" and self._ftp is not None:
            self._ftp.handle(msg)

    def _on_heartbeat(self, msg, source: tuple[int, int], now: float) -> None:
        with self.lock:
            if msg.type == MAV_TYPE_CAMERA:
                self._cameras.add(source)
                if source == self.status.companion:
                    self.status.companion_heartbeat = now
            elif is_autopilot_heartbeat(msg) and source[0] != 255:
                self.status.autopilot = source
                self.status.autopilot_heartbeat = now
        if self.options.companion == source:
            self._adopt(source)

    def _adopt(self, source: tuple[int, int]) -> None:
        """Lock onto the companion: the configured one, else the first camera (by heartbeat) that sends captures,
        images, status lines or values (a plain camera, such as BlueOS's camera manager, sends none of those)."""
        if self.status.companion is not None:
            return
        if self.options.companion is not None and source != self.options.companion:
            return
        log.info("companion found at system %d component %d", *source)
        with self.lock:
            self.status.companion = source
            self.status.companion_heartbeat = time.time()
        for msg, when in self._early_text.pop(source, ()):
            self._on_statustext(msg, when)
        self._early_text.clear()
        if self.options.ftp:
            self._ftp = FtpClient(self._send_ftp, source, own=(self.options.system_id, self.options.component_id),
                                  clock=self._clock)
            self._index_due = self._clock()  # learn the summary as it stands now

    def _send_ftp(self, system: int, component: int, payload: bytes) -> None:
        self._link.send(mav.MAVLink_file_transfer_protocol_message(0, system, component, list(payload)))

    # --- captures and pushes -------------------------------------------------------------------------------

    def _dive_ok(self, dive: str | None) -> bool:
        """False for a late message of an earlier dive; a new dive (the vehicle's store was reset, image indices
        start again) files the old one away and forgets every pairing made under the old indices."""
        verdict = self.gallery.use_dive(dive)
        if verdict == "new":
            log.info("dive %s: the vehicle's store was reset; earlier captures filed under dives/", dive)
            for pending in (self._waiting, self._early, self._expected, self._bound, self._orphans,
                            self._lost_push, self._crc, self._unverified):
                pending.clear()
            self._last_announced = None
            self._want_index()
        return verdict != "old"

    def _on_capture(self, msg) -> None:
        cap = capture_from_message(msg)
        if not self._dive_ok(cap.dive):
            return
        known = self.gallery.get(cap.image_index)
        if known is not None and not known.in_summary:
            return  # a re-sent announcement of a frame already trimmed out
        if not self.gallery.announce(cap):
            return
        log.info("capture %d at %.1f m", cap.image_index, cap.depth_m or 0.0)
        self._want_index()
        last = self._last_announced
        if last is not None and cap.image_index > last + 1:
            # image indices run without gaps: the captures in between were lost on the way. Their pushes are
            # still coming, in order, so they keep their place in the pairing queue; ask for the captures again.
            for ghost in range(max(last + 1, cap.image_index - 16), cap.image_index):
                if self.gallery.get(ghost) is None:
                    log.info("capture %d was lost on the way: asking for it again", ghost)
                    self.gallery.announce(Capture(image_index=ghost))
                    self._expect_push(ghost)
                    self._request_capture(ghost)
        self._last_announced = cap.image_index if last is None else max(last, cap.image_index)
        self._expect_push(cap.image_index)

    def _expect_push(self, index: int) -> None:
        if index in self._bound.values():
            return  # its marked push came first (the capture was lost and asked for again)
        if self._early:
            self._bind(self._early.popleft(), index)
        else:
            self._waiting.append((index, self._clock()))

    def _request_capture(self, index: int) -> None:
        """MAV_CMD_REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED, index): the camera protocol's way to re-get a capture."""
        if self.status.companion is None:
            return
        system, component = self.status.companion
        self._link.send(mav.MAVLink_command_long_message(
            system, component, mav.MAV_CMD_REQUEST_MESSAGE, 0,
            mav.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, index, 0, 0, 0, 0, 0))

    def _on_handshake(self, msg) -> None:
        self._on_push_result(self.images.handle(msg))
        if msg.size <= 0 or msg.packets <= 0:
            return
        progress = self.images.in_progress((msg.get_srcSystem(), msg.get_srcComponent()))
        if progress is None:
            return
        handshake_no = progress[0]
        marker, self._marker = self._marker, None
        if marker is not None:
            self._bind_marked(handshake_no, marker)
            return
        live = []
        for index, since in self._waiting:
            cap = self.gallery.get(index)
            if cap is not None and cap.in_summary and cap.thumbnail is None:
                live.append((index, since))
        # the oldest waiting capture whose thumbnail size (from index.json) matches, else the oldest of unknown size
        pick = next((i for i, _ in live if self._expected.get(i) == msg.size), None)
        if pick is None:
            pick = next((i for i, _ in live if i not in self._expected), None)
        self._waiting = deque((i, t) for i, t in live if i != pick)
        if pick is None:
            self._early.append(handshake_no)
        else:
            self._bind(handshake_no, pick)

    def _bind_marked(self, handshake_no: int, index: int) -> None:
        """The handshake the companion named with MRL_PUSH: it is that frame's, whatever arrived in between.
        A frame trimmed meanwhile still gets it (into removed/); one whose capture was lost is asked for again."""
        if self.gallery.get(index) is None:
            log.info("push for capture %d came before its capture: asking for the capture", index)
            self.gallery.announce(Capture(image_index=index))
            self._request_capture(index)
        self._waiting = deque((i, t) for i, t in self._waiting if i != index)
        self._bind(handshake_no, index)

    def _bind(self, handshake_no: int, index: int) -> None:
        self._bound[handshake_no] = index
        if handshake_no in self._orphans:
            self._store_push(index, self._orphans.pop(handshake_no))
        elif handshake_no in self._lost_push:
            self._fetch_thumbnail(index, partial=self._lost_push.pop(handshake_no))

    def _on_push_result(self, result: PushedImage | Abandoned | LostHandshake | None) -> None:
        if isinstance(result, Abandoned) and result.next_headless:
            result.next_headless = False
            self._on_push_result(result)
            result = LostHandshake(result.source)
        if isinstance(result, LostHandshake):
            # a push whose handshake was lost: it was for the oldest capture still waiting, which must come by FTP
            with self.lock:
                self.status.pushed_lost += 1
            marker, self._marker = self._marker, None
            if marker is not None:
                log.info("push for capture %d lost its handshake: FTP fallback", marker)
                self._waiting = deque((i, t) for i, t in self._waiting if i != marker)
                self._fetch_thumbnail(marker)
                return
            while self._waiting:
                index, _ = self._waiting.popleft()
                cap = self.gallery.get(index)
                if cap is not None and cap.in_summary and cap.thumbnail is None:
                    log.info("push for capture %d lost its handshake: FTP fallback", index)
                    self._fetch_thumbnail(index)
                    break
        elif isinstance(result, PushedImage):
            index = self._bound.pop(result.handshake_no, None)
            if index is None:
                self._orphans[result.handshake_no] = result
            else:
                self._store_push(index, result)
        elif isinstance(result, Abandoned):
            with self.lock:
                self.status.pushed_lost += 1
            index = self._bound.pop(result.handshake_no, None)
            log.info("push %d stalled (%d of %d packets): FTP fallback", result.handshake_no,
                     result.received_packets, result.packets)
            if index is None:
                self._lost_push[result.handshake_no] = result
            else:
                self._fetch_thumbnail(index, partial=result)

    def _store_push(self, index: int, image: PushedImage) -> None:
        expected = self._expected.get(index)
        if expected is not None and expected != len(image.data):
            log.warning("push of %d bytes paired with capture %d, which has %d: fetching it by FTP instead",
                        len(image.data), index, expected)
            self._fetch_thumbnail(index)
            return
        ext = "jpg" if image.kind == "jpeg" else image.kind
        self.gallery.add_thumbnail(index, image.data, ext=ext, via="push")
        if expected is None:
            self._want_index()  # the index brings the score, and sizes to pair the next pushes by
        self._verify(index, image.data)
        with self.lock:
            self.status.pushed_ok += 1

    def _verify(self, index: int, data: bytes) -> None:
        """A push may be paired by order, and a salvaged one is part push: check the bytes against the CRC32 that
        index.json gives for the companion's file (no extra request; a push usually lands before the index that
        lists it, so the check waits for that pull); on a mismatch fetch the whole file by name."""
        cap = self.gallery.get(index)
        path = mftp_path((cap.file_url if cap else None) or "") or f"/summary/{index}.jpg"
        if self._ftp is None or not path.endswith(".jpg"):
            return  # a WebP thumbnail on the server is not the JPEG that was pushed: nothing to compare
        crc = self._crc.get(index)
        if crc is None:
            self._unverified[index] = data
            self._want_index()
            return
        self._unverified.pop(index, None)
        self._checked(index, crc == crc32_mavftp(data))

    def _checked(self, index: int, ok: bool) -> None:
        if ok:
            with self.lock:
                self.status.verified += 1
            return
        with self.lock:
            self.status.mismatched += 1
        log.warning("thumbnail of capture %d is not the companion's (CRC differs): fetching it by name", index)
        self._fetch_thumbnail(index, replace=True)

    def _verify_by_request(self, index: int, data: bytes) -> None:
        """The fallback for a companion whose index.json has no CRC: one CalcFileCRC32 request."""
        cap = self.gallery.get(index)
        path = mftp_path((cap.file_url if cap else None) or "") or f"/summary/{index}.jpg"
        if self._ftp is None:
            return

        def checked(_path: str, crc: int | None, error: str) -> None:
            if crc is None:
                log.debug("CRC of %s: %s", path, error)  # e.g. trimmed meanwhile: nothing to fix
                return
            self._checked(index, crc == crc32_mavftp(data))

        self._ftp.crc(path, checked)

    def _fetch_thumbnail(self, index: int, *, replace: bool = False, partial: Abandoned | None = None) -> None:
        """Pull the thumbnail by FTP; with the ``partial`` push it came from, only the packets the push lost."""
        cap = self.gallery.get(index)
        dive = self.gallery.dive
        if cap is None or not cap.in_summary or (dive, index) in self._fetching:
            return
        if cap.thumbnail is not None and not replace:
            return
        if self._ftp is None:
            return
        path = mftp_path(cap.file_url or "") or f"/summary/{index}.jpg"
        self._fetching.add((dive, index))

        def done(_path: str, data: bytes | None, error: str) -> None:
            self._fetching.discard((dive, index))
            with self.lock:
                if data is None:
                    self.status.ftp_failed += 1
                else:
                    self.status.ftp_ok += 1
            if data is None:
                log.warning("FTP %s: %s", path, error)
                return
            if self.gallery.dive != dive:
                return  # the vehicle's store was reset meanwhile: this index now names another frame
            now_cap = self.gallery.get(index)
            if now_cap is not None and (replace or now_cap.thumbnail is None):
                ext = path.rsplit(".", 1)[-1] if "." in path.rsplit("/", 1)[-1] else "jpg"
                self.gallery.add_thumbnail(index, data, ext=ext, via="push+ftp" if known else "ftp")
                if known:
                    self._verify(index, data)

        known, known_size = {}, None
        if partial is not None and partial.kind == "jpeg" and path.endswith(".jpg"):
            known, known_size = partial.chunks, partial.size  # the same JPEG file: fill in only the holes
        self._ftp.fetch(path, done, known=known, known_size=known_size)

    # --- status and index ----------------------------------------------------------------------------------

    def _on_statustext(self, msg, now: float) -> None:
        text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else msg.text
        text = text.rstrip("\0")
        with self.lock:
            line = {"time": now, "severity": int(msg.severity), "text": text}
            self.status.statustext.append(line)
            if line["severity"] <= SEVERITY_WARNING:
                self.status.warnings.append(line)
        facts = parse_statustext(text)
        for index in facts.removed:
            if self.gallery.remove(index):
                log.info("capture %d trimmed out of the summary", index)
            self._waiting = deque((i, t) for i, t in self._waiting if i != index)
        for index, score in facts.scores.items():
            self.gallery.update_tags(index, score=score)
        for index, topic in facts.topics.items():
            self.gallery.update_tags(index, topic=topic)
        if facts.removed or facts.summary_changed or facts.added:
            self._want_index()

    def _want_index(self) -> None:
        if self._ftp is None:
            return
        due = max(self._clock(), self._index_pulled_at + self.options.index_refresh_s)
        if self._index_due is None or due < self._index_due:
            self._index_due = due

    def _on_index(self, _path: str, data: bytes | None, error: str) -> None:
        if data is None:
            log.warning("FTP %s: %s", INDEX_PATH, error)
            with self.lock:
                self.status.ftp_failed += 1
            return
        try:
            captures = parse_index(data)
            dive = index_dive(data)
            topics = index_topics(data)
        except (ValueError, UnicodeDecodeError) as err:
            log.warning("%s: not JSON this tool understands (%s)", INDEX_PATH, err)
            return
        if not self._dive_ok(dive):
            return  # asked for before the store was reset: it lists the earlier dive
        with self.lock:
            self.status.index_pulls += 1
            self.status.ftp_ok += 1
        if topics is not None:
            self.gallery.set_topics(topics)
        asked = self._ftp.started_wall if self._ftp is not None else None
        gone = set(self.gallery.mirror([c.image_index for c in captures], announced_before=asked))
        # frames that left without a push keep no place in the pairing queue (else every later push shifts)
        self._waiting = deque((i, t) for i, t in self._waiting if i not in gone)
        waiting = {i for i, _ in self._waiting}
        for cap in captures:
            if (cap.file_url or "").endswith(".jpg"):  # pushes are JPEG: comparable
                if cap.thumbnail_bytes is not None:
                    self._expected[cap.image_index] = cap.thumbnail_bytes
                if cap.thumbnail_crc32 is not None:
                    self._crc[cap.image_index] = cap.thumbnail_crc32
            tags = {k: getattr(cap, k) for k in ("time_utc", "depth_m", "heading_deg", "q", "lat", "lon", "alt_m",
                                                 "score", "topic", "file_url", "thumbnail_crc32")}
            self.gallery.update_tags(cap.image_index, **tags)
            known = self.gallery.get(cap.image_index)
            if known is None:
                continue
            if (known.thumbnail is not None and known.thumbnail_via == "push" and cap.thumbnail_bytes is not None
                    and known.thumbnail_bytes != cap.thumbnail_bytes):
                # the push paired with this capture was another frame's (a thumbnail dropped unannounced):
                # fetch the right one by name
                log.warning("capture %d: pushed thumbnail has %d bytes, the companion says %d: re-fetching",
                            cap.image_index, known.thumbnail_bytes, cap.thumbnail_bytes)
                self._unverified.pop(cap.image_index, None)
                self._fetch_thumbnail(cap.image_index, replace=True)
                continue
            if known.thumbnail is not None:
                continue
            # a frame we never heard announced has no push coming: fetch it now
            if cap.image_index not in waiting and cap.image_index not in self._bound.values():
                self._fetch_thumbnail(cap.image_index)
        self._verify_waiting({c.image_index for c in captures})

    def _verify_waiting(self, listed: set[int]) -> None:
        """After an index pull: check the pushes that waited for their CRC; an index without CRCs (another
        companion) gets the CalcFileCRC32 request instead; frames trimmed meanwhile need no check."""
        for index, data in list(self._unverified.items()):
            cap = self.gallery.get(index)
            if cap is None or not cap.in_summary:
                del self._unverified[index]
            elif index in self._crc:
                self._verify(index, data)
            elif index in listed:
                del self._unverified[index]
                self._verify_by_request(index, data)
            # else: announced after this index was built; the next pull lists it

    # --- full frames on demand -----------------------------------------------------------------------------

    def full_frame(self, index: int, timeout: float = FULL_FRAME_TIMEOUT_S) -> Path | None:
        """The full-resolution frame of a summary frame of the current dive, fetched by FTP
        (``/summary/full/<n>.jpg``) the first time it is asked for and kept in DIR/full/; None when the companion
        no longer has it or the link did not deliver it in time. Called from the web server's threads: the fetch
        itself runs on the receive loop, which owns the FTP client."""
        dive = self.gallery.dive
        cached = self.gallery.full_path(index, dive)
        if cached.is_file():
            return cached
        done = threading.Event()
        result: list[Path | None] = [None]

        def start() -> None:
            cap = self.gallery.get(index)
            if self._ftp is None or cap is None or not cap.in_summary or self.gallery.dive != dive:
                done.set()
                return

            def fetched(_path: str, data: bytes | None, error: str) -> None:
                if data and self.gallery.dive == dive:
                    result[0] = self.gallery.add_full(index, data, dive)
                else:
                    log.info("full frame %d: %s", index, error or "not fetched")
                done.set()

            self._ftp.fetch(f"/summary/full/{index}.jpg", fetched)

        self._requests.put(start)
        done.wait(timeout)
        return result[0]

    # --- the operator's marks --------------------------------------------------------------------------------

    def mark(self, index: int, kind: str, timeout: float = MARKS_TIMEOUT_S) -> str:
        """The page's button: mark frame ``index`` "like", "unlike" or "none" (unmark), on top of the marks this
        tool sent before, and send the whole set; returns "" once the companion took it, else why not."""
        if kind not in ("like", "unlike", "none"):
            raise ValueError(f"mark {kind!r}: expected like, unlike or none")
        with self.lock:
            like = [i for i in self.marks["like"] if i != index] + ([index] if kind == "like" else [])
            unlike = [i for i in self.marks["unlike"] if i != index] + ([index] if kind == "unlike" else [])
        error = self.send_marks(like, unlike, timeout)
        if not error:
            with self.lock:
                self.marks = {"like": like, "unlike": unlike}
        return error

    def send_marks(self, like: list[int], unlike: list[int], timeout: float = MARKS_TIMEOUT_S) -> str:
        """Upload ``/config/marks.json`` (image indices "more like this" / "not this") to the companion; returns
        "" once it accepted them, else why not. Called from the web server's threads; the upload runs on the
        receive loop, which owns the FTP client."""
        from companion.topside.marks_upload import MARKS_PATH, marks_document

        data = marks_document(like, unlike)  # ValueError: malformed, as the companion would refuse it
        done = threading.Event()
        result = ["no answer from the companion"]

        def start() -> None:
            if self._ftp is None:
                result[0] = "no companion yet (or --no-ftp)"
                done.set()
                return

            def sent(_path: str, got: bytes | None, error: str) -> None:
                result[0] = "" if got is not None else (error or "not sent")
                done.set()

            self._ftp.upload(MARKS_PATH, data, sent)

        self._requests.put(start)
        done.wait(timeout)
        if not result[0]:
            log.info("marks sent: like %s, unlike %s", like, unlike)
        return result[0]

    # --- for the web page ----------------------------------------------------------------------------------

    def write_offline_page(self) -> None:
        """DIR/index.html (+ app.js, state.js): the page as of now, opened from disk without a server."""
        try:
            write_offline_page(self.gallery.root, self.snapshot())
        except OSError as err:
            log.warning("%s: cannot write the offline page (%s)", self.gallery.root, err.strerror or err)

    def snapshot(self) -> dict:
        """A JSON-ready view of the link, the companion and the summary (newest first)."""
        now = time.time()
        with self.lock:
            s = self.status
            link = {
                "connect": self.options.connect,
                "messages": s.messages,
                "last_message_age_s": None if s.last_message is None else round(now - s.last_message, 1),
                "lost_packets": s.lost_packets,
                "autopilot": list(s.autopilot) if s.autopilot else None,
                "autopilot_heartbeat_age_s": _age(now, s.autopilot_heartbeat),
                "pushed_ok": s.pushed_ok, "pushed_lost": s.pushed_lost,
                "ftp_ok": s.ftp_ok, "ftp_failed": s.ftp_failed, "index_pulls": s.index_pulls,
                "verified": s.verified, "mismatched": s.mismatched,
            }
            companion = {
                "id": list(s.companion) if s.companion else None,
                "heartbeat_age_s": _age(now, s.companion_heartbeat),
                "values": {k: (v if math.isfinite(v) else None) for k, v in s.values.items()},  # strict JSON
                "values_age_s": _age(now, s.values_at),
                "statustext": list(s.statustext)[::-1],
                "warnings": list(s.warnings)[::-1],
                "depth_track": list(s.depth_track),
            }
            marks = {k: list(v) for k, v in self.marks.items()}
        summary = [_capture_view(c) for c in self.gallery.summary()]
        topics = [t.to_dict() for t in self.gallery.topics()]
        return {"time": now, "link": link, "companion": companion, "dive": self.gallery.dive, "summary": summary,
                "topics": topics, "thumbnails_waiting": self.gallery.missing_thumbnails(), "marks": marks}


def _age(now: float, then: float | None) -> float | None:
    return None if then is None else round(now - then, 1)


def _capture_view(c: Capture) -> dict:
    return {
        "image_index": c.image_index, "dive": c.dive, "time_utc": c.time_utc, "depth_m": c.depth_m, "heading_deg": c.heading_deg,
        "score": c.score, "topic": c.topic, "lat": c.lat, "lon": c.lon, "alt_m": c.alt_m, "thumbnail": c.thumbnail,
        "via": c.thumbnail_via,
        "bytes": c.thumbnail_bytes,
    }
