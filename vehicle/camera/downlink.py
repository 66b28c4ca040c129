"""Everything the companion says to the surface, on one MAVLink link and one byte budget.

The live loop hands ``Downlink.publish`` each summary event and ``update_status`` its latest numbers; this
object turns them into the camera protocol (CAMERA_IMAGE_CAPTURED, answers to requests), pushed thumbnails
(DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA), a MAVLink FTP tree (/summary/index.json, thumbnails, full
frames, /config/queries.txt), STATUSTEXT lines, 1 Hz NAMED_VALUE_FLOAT values and the parameter protocol, and
queues all of it through one ``LinkBudget`` so the link is never asked for more than it has.

Requests arrive on the link's receive loop, which only parses: this object hands each one to a worker (FTP on
one, commands and parameters on another, so a full frame's JPEG encoding never delays a PARAM_SET answer) and
the worker's replies go out through the budget's one sender thread.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import cv2
from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.camera import status as st
from vehicle.camera.capture_frame import CaptureEvent, CaptureFrame
from vehicle.camera.captures import CaptureLog, added_text, thumbnail_path, trimmed_text
from vehicle.camera.component import CameraComponent, CameraIdentity, firmware_version_of
from vehicle.camera.ftp_server import FtpServer, VirtualTree, crc32_ardupilot
from vehicle.camera.link_params import LINK_BPS, THUMB_B, link_params
from vehicle.camera.params import REQUEST_TYPES as PARAM_REQUESTS
from vehicle.camera.params import ParamServer, ParamSpec
from vehicle.camera.request_worker import RequestWorker
from vehicle.camera.requests import RequestRouter, requester
from vehicle.camera.thumbnails import Thumbnail, make_thumbnail
from vehicle.link.budget import LinkBudget, Priority
from vehicle.link.fair_replies import FairReplies, Requester, UnsignedSlice
from vehicle.link.request_gate import RequestGate
from vehicle.link.warning_bucket import WarningBucket
from vehicle.protocol.ftp import Op
from vehicle.protocol.image_push import push_messages
from vehicle.protocol.marks import MARKS_PATH, format_marks, marks_text, parse_marks
from vehicle.protocol.queries import QueryTopic, format_queries, parse_queries
from vehicle.settings import SurfaceConfig

log = logging.getLogger(__name__)

QUERIES_PATH = "/config/queries.txt"
INDEX_PATH = "/summary/index.json"
FULL_QUALITY = 90
_FTP_BULK_OPS = frozenset({Op.READ_FILE, Op.BURST_READ_FILE, Op.LIST_DIRECTORY})


@dataclass
class _Held:
    frame: CaptureFrame
    thumb: Thumbnail
    encoded: dict[str, bytes] = field(default_factory=dict)


def _frame_tags(frame: CaptureFrame) -> dict[str, Any]:
    pose = frame.pose
    tags: dict[str, Any] = {
        "image_index": frame.image_index, "topic": getattr(frame, "topic", ""), "frame_index": frame.frame_index,
        "time_s": round(frame.time_s, 3),
        "capture_time": frame.capture_time,
        "utc": datetime.fromtimestamp(frame.capture_time, timezone.utc).isoformat(timespec="milliseconds"),
        "score": _json_safe(round(float(frame.score), 4)), "enhanced": bool(frame.enhanced),
        "below_threshold": bool(getattr(frame, "below_threshold", False)),  # a stand-in: nothing passed
        "pilot": bool(getattr(frame, "pilot", False)),  # kept by the pilot's shutter
    }
    raw_score = getattr(frame, "raw_score", None)
    if raw_score is not None:
        tags["raw_score"] = _json_safe(round(float(raw_score), 4))
    if pose is not None:
        tags["pose"] = {k: _json_safe(v) for k, v in pose.to_dict().items() if v is not None}
    return tags


def _json_safe(value: Any) -> Any:
    """Strict JSON has no NaN or Infinity (a browser's JSON.parse rejects them): unknown becomes null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


class Downlink:
    """Camera, image push, FTP, status and parameters on ``link``, within ``cfg.budget_bytes_per_s``.

    ``params`` is the tunable set; ``saved_params`` what an earlier run persisted and ``persist_params`` how to
    save a change (both from the app: this side touches no files);
    ``loader`` fetches an old capture's frame from the store by image index; ``image_count`` is how many summary
    frames earlier runs took; ``queries`` the topics in force (one, named ``default_topic``, unless several are
    followed).
    """

    def __init__(self, link: Any, cfg: SurfaceConfig, *, params: list[ParamSpec] | None = None,
                 saved_params: dict[str, float] | None = None,
                 persist_params: Callable[[dict[str, float]], None] | None = None, loader: Callable[[int], CaptureFrame | None] | None = None,
                 image_count: int = 0, queries: list[QueryTopic] | None = None, default_topic: str = "main",
                 identity: CameraIdentity | None = None, version: str = "", dive: str = "",
                 stored_jpeg: Callable[[int, bool], bytes | None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.link = link
        self.cfg = cfg
        self.clock = clock
        self.version = version
        self.thumbnail_bytes = cfg.thumbnail_bytes
        self.ext = "webp" if cfg.thumbnail_format == "webp" else "jpg"
        self.budget = LinkBudget(link, cfg.budget_bytes_per_s, clock=clock)
        self.dive = dive
        """The store's dive id (``Store.dive``): in every file_url and in index.json, so the surface never files a
        new dive's frames under an old dive's image indices."""
        self.captures = CaptureLog(clock=clock, initial_count=image_count, loader=loader, ext=self.ext, dive=dive)
        self._stored_jpeg = stored_jpeg
        """(image index, raw) -> the frame's JPEG as the app stored it; served as is, so downloads equal the store."""
        self._earlier_runs = image_count
        self.camera = CameraComponent(self.captures, system_id=lambda: link.system_id,
                                      component_id=link.component_id,
                                      identity=identity or CameraIdentity(firmware_version=firmware_version_of(version)))
        self.camera.shutter.on_change = self._camera_state
        self.status = st.StatusReporter(self.captures.time_boot_ms)
        self.params = ParamServer(self._with_own_params(params or []), system_id=lambda: link.system_id,
                                  component_id=link.component_id, saved=saved_params,
                                  persist=persist_params)
        self.params.on_change(self._own_param)
        self.tree = VirtualTree()
        signing = getattr(link, "signing", None)
        # with a key, two sessions are kept for signed clients: unsigned strangers cannot lock them out
        self.ftp = FtpServer(self.tree, writable=cfg.ftp_writable,
                             reserve_signed=2 if getattr(signing, "enabled", False) else 0)
        self._held: dict[int, _Held] = {}
        self._lock = threading.Lock()
        self.default_topic = default_topic
        self._queries: list[QueryTopic] = list(queries or [])
        self._query_cbs: list[Callable[[list[QueryTopic]], None]] = []
        self._marks: tuple[list[int], list[int]] = ([], [])
        self._marks_cbs: list[Callable[[list[int], list[int]], None]] = []
        self._unsubscribe: Callable[[], None] | None = None
        self._refusals_wired = False
        self._stop = threading.Event()
        self._status_thread: threading.Thread | None = None
        self.ftp_worker = RequestWorker("surface-ftp")
        self.control_worker = RequestWorker("surface-control")
        self.requests = RequestGate(on_flood=self._flood)
        """Commands and parameter requests per requester and second (FTP is bounded by its sessions)."""
        self._floods: set[Requester] = set()
        self._stranger_warnings = WarningBucket()
        self.router = RequestRouter(lambda: (link.system_id, link.component_id), self.requests)
        """Request type -> handler: the one place that decides whether a request is for us."""
        for kind in ("COMMAND_LONG", "COMMAND_INT"):
            self.router.route(kind, self._answer(self.camera.answer), self.control_worker)
        for kind in PARAM_REQUESTS:
            self.router.route(kind, self._answer(self.params.answer, unique=kind == "PARAM_REQUEST_LIST"),
                              self.control_worker)
        self.router.route("FILE_TRANSFER_PROTOCOL", self._on_ftp, self.ftp_worker, broadcast=False, gated=False)
        self.tree.put(INDEX_PATH, self.index_json, size=lambda: len(self.index_json()))
        queries_text = lambda: format_queries(self._queries, self.default_topic).encode()  # noqa: E731
        self.tree.put(QUERIES_PATH, queries_text, size=lambda: len(queries_text()))
        self.tree.uploadable(QUERIES_PATH, self._upload_queries)
        self.tree.put(MARKS_PATH, lambda: format_marks(*self._marks), size=lambda: len(format_marks(*self._marks)))
        self.tree.uploadable(MARKS_PATH, self._upload_marks)
        self.unsigned_slice = UnsignedSlice(lambda: self.budget.rate, clock=clock)
        """The one share of the link all answers to unsigned requesters draw on, however many ids they use."""
        self.replies = FairReplies(self.unsigned_slice, on_flood=self._flood, clock=clock)
        """Answers to commands, parameter and small FTP requests, per requester, signed ones first."""
        self.bulk_replies = FairReplies(self.unsigned_slice, per_requester=16, work_conserving=True,
                                        on_flood=self._flood, clock=clock)
        """FTP data replies, per requester, signed ones first (bursts come from the FTP server itself)."""
        self.budget.add_source(Priority.CONTROL, self.replies.next)
        # signed links' bursts, then the data replies (signed first), then strangers' bursts: an unsigned burst
        # never goes ahead of a signed client's data (it had gone first, whatever the slice)
        self.budget.add_source(Priority.BULK, lambda: self._next_burst(signed=True))
        self.budget.add_source(Priority.BULK, self.bulk_replies.next)
        self.budget.add_source(Priority.BULK, lambda: self._next_burst(signed=False))
        for name, value in self.params.restored.items():
            self._own_param(name, value)

    # ---- wiring ---------------------------------------------------------------------------------------------

    def start(self) -> None:
        """Listen for requests, start the budget's sender and the status tick; announce the start."""
        if self._unsubscribe is not None:
            return
        self._stop.clear()
        self.ftp_worker.start()
        self.control_worker.start()
        self._unsubscribe = self.link.subscribe(self.router, self.router.types)
        if not self._refusals_wired and hasattr(self.link, "on_refused"):
            self.link.on_refused(self._on_refused)
            self._refusals_wired = True
        self.budget.start()
        self._status_thread = threading.Thread(target=self._status_loop, name="surface-status", daemon=True)
        self._status_thread.start()
        self.event(*st.started_text(self.version or "companion"))

    def stop(self) -> None:
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        self._stop.set()
        if self._status_thread is not None:
            self._status_thread.join(timeout=5)
            self._status_thread = None
        self.ftp_worker.stop()
        self.control_worker.stop()
        self.budget.stop()

    def __enter__(self) -> Downlink:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def on_queries_changed(self, callback: Callable[[list[QueryTopic]], None]) -> None:
        """``callback(topics)`` after a client uploaded a valid queries file (raise ValueError to refuse)."""
        self._query_cbs.append(callback)

    def on_marks_changed(self, callback: Callable[[list[int], list[int]], None]) -> None:
        """``callback(like, unlike)`` (image indices) after a client uploaded a valid marks file; the callback
        raises ValueError to refuse it (e.g. a frame it does not hold), which the client gets as a NAK."""
        self._marks_cbs.append(callback)

    def _camera_state(self) -> None:
        """CAMERA_CAPTURE_STATUS and STORAGE_INFORMATION as they are now: sent on every change (a capture in or
        out, a shutter done), the latest replacing one still queued."""
        for msg in (self.camera.capture_status(), self.camera.storage_information()):
            self.budget.submit(msg, Priority.STATUS, tag=("camera", msg.get_type()), replace=True)

    def set_marks(self, like: list[int], unlike: list[int]) -> None:
        """The marks in force, as /config/marks.json shows them (restored at start, cleared with the queries)."""
        self._marks = (list(like), list(unlike))

    def on_param_changed(self, callback: Callable[[str, float], None], *, replay: bool = True) -> None:
        """``callback(name, value)`` on every accepted PARAM_SET; ``replay`` first hands it the values restored
        from the parameter file, so a restart resumes with what the operator last set."""
        self.params.on_change(callback)
        if replay:
            for name, value in self.params.restored.items():
                callback(name, value)

    def set_dive(self, dive: str) -> None:
        """Announce under ``dive`` from now on (the store could not persist its next index and took a new dive id):
        new captures' file_url and index.json name it, and the held frames' thumbnails move to its folder."""
        with self._lock:
            old, self.dive = self.dive, dive
            held = [(idx, h.thumb.data) for idx, h in self._held.items()]
        self.captures.dive = dive
        for idx, data in held:
            self.tree.put(thumbnail_path(idx, self.ext, dive), data)
            if old:
                self.tree.remove(thumbnail_path(idx, self.ext, old))

    def set_queries(self, topics: list[QueryTopic]) -> None:
        """The topics in force, as /config/queries.txt and index.json show them."""
        self._queries = list(topics)

    # ---- outgoing -------------------------------------------------------------------------------------------

    def publish(self, event: CaptureEvent) -> None:
        """Announce a frame that entered (capture, thumbnail, push) or left (STATUSTEXT, files gone) the summary.

        A frame an earlier run took (``image_index`` below the ``image_count`` given at start, i.e. the resumed
        summary) goes back on the FTP tree and answers re-requests, but is neither counted nor announced again.
        """
        frame = event.frame
        idx = frame.image_index
        if event.kind == "added":
            ident = self.camera.identity
            if not ident.width and frame.image is not None:  # CAMERA_INFORMATION reports what frames really are
                ident.height, ident.width = frame.image.shape[:2]
            thumb = make_thumbnail(frame.image, self.thumbnail_bytes, max_side=self.cfg.thumbnail_max_side,
                                   fmt=self.cfg.thumbnail_format)
            with self._lock:
                self._held[idx] = _Held(frame, thumb)
                gone = self._prune(event.summary)
            for old in gone:
                self._forget(old)
            self.tree.put(thumbnail_path(idx, self.ext), thumb.data)
            if self.dive:
                self.tree.put(thumbnail_path(idx, self.ext, self.dive), thumb.data)
            self.tree.put(f"/summary/full/{idx}.jpg", lambda i=idx: self._full(i),
                          size=lambda i=idx: self._full_size(i))
            if frame.raw_image is not None:
                self.tree.put(f"/summary/raw/{idx}.jpg", lambda i=idx: self._full(i, raw=True),
                              size=lambda i=idx: self._full_size(i, raw=True))
            resumed = idx < self._earlier_runs
            capture = self.captures.record(frame, count=not resumed)
            if resumed:
                self.status.update(summary=len(self._held))
                return
            self.budget.submit(capture, Priority.STATUS)
            several = len(self._queries) > 1
            self.event(added_text(frame, len(event.summary) or len(self._held), topic=several))
            if self.cfg.push:
                push = thumb if thumb.format == "jpeg" else make_thumbnail(
                    frame.image, self.thumbnail_bytes, max_side=self.cfg.thumbnail_max_side)
                # the image protocol carries no image index: a NAMED_VALUE_INT right before the handshake says
                # which frame follows (a repeated CAMERA_IMAGE_CAPTURED would put a second QGC map marker down)
                marker = st.push_marker(idx, self.captures.time_boot_ms())
                for msg in [marker, *push_messages(push.data, push.width, push.height, push.quality)]:
                    self.budget.submit(msg, Priority.THUMBNAIL, tag=("thumb", idx))
        else:
            with self._lock:
                self._held.pop(idx, None)
                gone = self._prune(event.summary)
            for old in [idx, *gone]:
                self._forget(old)
            self.event(trimmed_text(frame, len(event.summary)))
        self.status.update(summary=len(self._held))
        self._camera_state()

    def _prune(self, summary: list[int]) -> list[int]:
        """Drop frames the event's summary list no longer holds; called with the lock held, so it only
        returns them: their files and queued pushes are forgotten after the lock is released (the FTP server
        reads the tree, which takes this lock, while holding its own)."""
        if not summary:
            return []
        gone = [i for i in self._held if i not in summary]
        for old in gone:
            self._held.pop(old)
        return gone

    def _forget(self, idx: int) -> None:
        self.tree.remove(thumbnail_path(idx, self.ext))
        self.tree.remove(thumbnail_path(idx, self.ext, self.dive))
        self.tree.remove(f"/summary/full/{idx}.jpg")
        self.tree.remove(f"/summary/raw/{idx}.jpg")
        self.budget.drop(("thumb", idx))

    def _full(self, idx: int, raw: bool = False) -> bytes:
        """The full-resolution frame as JPEG, encoded on first request and kept while the frame is held."""
        with self._lock:
            held = self._held.get(idx)
        if held is None:
            return b""
        image = held.frame.raw_image if raw else held.frame.image
        if image is None:
            return b""
        key = "raw" if raw else "full"
        if key not in held.encoded:
            stored = self._stored_jpeg(idx, raw) if self._stored_jpeg is not None else None
            if stored:
                held.encoded[key] = stored
            else:  # no store (memory only) or not written yet: encode it here
                ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, FULL_QUALITY])
                held.encoded[key] = buf.tobytes() if ok else b""
        return held.encoded[key]

    def _full_size(self, idx: int, raw: bool = False) -> int:
        """What a listing shows for a full frame: its JPEG size once encoded, 0 before (listing never encodes)."""
        with self._lock:
            held = self._held.get(idx)
        return 0 if held is None else len(held.encoded.get("raw" if raw else "full", b""))

    def index_json(self) -> bytes:
        """The current summary with its tags, newest first (what /summary/index.json serves)."""
        with self._lock:
            held = sorted(self._held.values(), key=lambda h: h.frame.image_index, reverse=True)
        items = []
        for h in held:
            tags = _frame_tags(h.frame)
            idx = h.frame.image_index
            tags.update(thumbnail=thumbnail_path(idx, self.ext, self.dive), full=f"/summary/full/{idx}.jpg",
                        thumbnail_bytes=len(h.thumb.data), thumbnail_crc32=crc32_ardupilot(h.thumb.data),
                        width=h.thumb.width, height=h.thumb.height)
            if h.frame.raw_image is not None:
                tags["raw"] = f"/summary/raw/{idx}.jpg"
            items.append(tags)
        topics = [{"name": t.name, "positive": t.positive, "negatives": list(t.negatives),
                   "held": sum(item["topic"] == t.name for item in items)} for t in self._queries]
        body = {"image_count": self.captures.image_count, "dive": self.dive, "topics": topics, "summary": items}
        return json.dumps(body, separators=(",", ":"), allow_nan=False).encode()

    def event(self, text: str, severity: int = st.INFO) -> None:
        """One STATUSTEXT line (cut to 50 characters)."""
        self.budget.submit(st.status_text(text, severity), Priority.STATUS)

    def update_status(self, **values: float | None) -> None:
        """Latest fps, score, summary, depth_m (see ``StatusReporter.update``); sent on the next tick."""
        self.status.update(**values)

    def _status_loop(self) -> None:
        period = 1.0 / self.cfg.status_hz
        while not self._stop.wait(period):
            self.status.update(link_bps=self.budget.in_use_bps())
            for msg in self.status.messages():
                self.budget.submit(msg, Priority.STATUS, tag=("nvf", msg.name), replace=True)

    # ---- incoming -------------------------------------------------------------------------------------------

    def handle_requests(self, mtype: str, answer: Callable[[mav.MAVLink_message], list[mav.MAVLink_message]]) -> None:
        """Answer each ``mtype`` addressed to this component with ``answer(msg)``'s replies (run on the control
        worker, sent fairly per requester); call before ``start``. The target check is the router's."""
        self.router.route(mtype, self._answer(answer), self.control_worker)

    def _answer(self, answer: Callable[[mav.MAVLink_message], list[mav.MAVLink_message]], *,
                unique: bool = False) -> Callable[[mav.MAVLink_message], None]:
        """A route's handler: queue ``answer(msg)``'s replies for the requester. ``unique``: one answer of this kind
        per requester at a time (a repeated PARAM_REQUEST_LIST while its answers still wait adds nothing, so a flood
        of them costs its sender a bounded share, never the others' answers)."""
        def handle(msg: mav.MAVLink_message) -> None:
            replies = answer(msg)
            if replies:
                self.replies.submit(requester(msg), replies, tag=msg.get_type() if unique else None, unique=unique)
                self.budget.wake()
        return handle

    def _on_ftp(self, msg: mav.MAVLink_message) -> None:
        if not self.cfg.ftp:
            return
        who = requester(msg)
        request = bytes(msg.payload)
        replies = self.ftp.handle(request, who[:2], signed=who[2])
        if not replies:
            self.budget.wake()  # a burst may have started
            return
        # data replies are bulk; the small answers (open, close, CRC, write acks, refusals) are command answers
        opcode = request[3] if len(request) > 3 else 0
        self._send_ftp(who, replies, Priority.BULK if opcode in _FTP_BULK_OPS else Priority.CONTROL)

    def _send_ftp(self, who: Requester, replies: list[bytes], prio: Priority) -> None:
        queue = self.bulk_replies if prio == Priority.BULK else self.replies
        for payload in replies:
            reply = mav.MAVLink_file_transfer_protocol_message(0, who[0], who[1], list(payload))
            # a client retransmits while our answer still waits for budget: one copy in the queue is enough
            queue.submit(who, [reply], tag=("ftp", bytes(payload[:12])), unique=True)
        self.budget.wake()

    def _flood(self, who: Requester) -> None:
        """Said once per requester that asked too fast or whose replies overflowed its share (the counts are in
        ``requests.stats()`` and ``replies.stats()``); unsigned requesters' warnings share one small bucket."""
        with self._lock:
            if who in self._floods:
                return
            self._floods.add(who)
        name = f"{who[0]}/{who[1]}{'' if who[2] else ' unsigned'}"
        if who[2] or self._stranger_warnings.take():  # made-up unsigned ids are free: their warnings share a bucket
            log.warning("request flood from %s: replies beyond its share are dropped (further ones only counted)",
                        name)
            self.event(f"Request flood from {name}: replies dropped"[:50], st.WARNING)

    def _on_refused(self, msg: mav.MAVLink_message, reason: str) -> None:
        """An FTP write the link's signing refused still gets its NAK (on the FTP worker, off the receive loop)."""
        if msg.get_type() != "FILE_TRANSFER_PROTOCOL" or not self.cfg.ftp or not self.router.for_us(msg):
            return
        who = requester(msg)
        request = bytes(msg.payload)
        self.ftp_worker.submit(lambda: self._send_ftp(who, self.ftp.refuse(request), Priority.CONTROL))

    def _next_burst(self, *, signed: bool) -> mav.MAVLink_message | None:
        got = self.ftp.next_burst(signed)
        if got is None:
            return None
        (sysid, compid), payload = got
        return mav.MAVLink_file_transfer_protocol_message(0, sysid, compid, list(payload))

    def _upload_queries(self, data: bytes) -> None:
        try:
            topics = parse_queries(data, self.default_topic)
        except ValueError as err:  # the NAK says only "refused": the operator reads why here
            self.event(f"Queries refused: {err}"[:50], st.WARNING)
            raise
        for callback in self._query_cbs:
            callback(topics)
        self._queries = topics
        if len(topics) == 1 and topics[0].name == self.default_topic:
            self.event(f"Queries set: {topics[0].positive}"[:50])
        else:
            self.event(f"Topics set: {', '.join(t.name for t in topics)}"[:50])

    def _upload_marks(self, data: bytes) -> None:
        try:
            like, unlike = parse_marks(data)
            for callback in self._marks_cbs:
                callback(like, unlike)
        except ValueError as err:  # the NAK says only "refused": the operator reads why here
            self.event(f"Marks refused: {err}"[:50], st.WARNING)
            raise
        self._marks = (like, unlike)
        self.event(marks_text(like, unlike))

    def _with_own_params(self, params: list[ParamSpec]) -> list[ParamSpec]:
        """The app's parameters with this link's own (``link_params``): defined here from ``cfg`` and applied only
        by ``_own_param``; served where the app's list names them (its wire order), else after it."""
        own = {spec.name: spec for spec in link_params(self.cfg)}
        served = [own.pop(spec.name, spec) for spec in params]
        return served + list(own.values())

    def _own_param(self, name: str, value: float) -> None:
        """The one place MERL_THUMB_B and MERL_LINK_BPS take effect (a PARAM_SET, or a saved value at start)."""
        if name == THUMB_B:
            self.thumbnail_bytes = int(value)
        elif name == LINK_BPS:
            self.budget.set_rate(value)
