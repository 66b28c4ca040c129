"""Pairing each CAMERA_IMAGE_CAPTURED with the thumbnail pushed for it (DATA_TRANSMISSION_HANDSHAKE +
ENCAPSULATED_DATA); what no push brings is fetched by FTP (``gallery_sync``).

The image protocol carries no image index, so our companion sends a NAMED_VALUE_INT ``MRL_PUSH`` = image index
right before each handshake, and that handshake belongs to that frame. Without a marker (another sender, or the
marker lost) pushes are paired with captures in the order both arrive (the companion announces a frame, then
pushes its thumbnail; thumbnails of frames trimmed before they were sent are dropped, and the trim is announced
first): each handshake takes the oldest capture still waiting. An image whose packets never all arrive is fetched
by FTP instead. Runs on the receive loop.
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.topside.capture import Capture
from companion.topside.gallery_sync import GallerySync
from companion.topside.messages import capture_from_message
from companion.topside.surface_state import (
    MAX_BOUND,
    MAX_UNPAIRED,
    MAX_WAITING,
    REQUEST_BURST,
    REQUEST_REFILL_S,
    SurfaceContext,
)
from vehicle.link.warning_bucket import WarningBucket
from vehicle.protocol.image_push import Abandoned, ImageReceiver, LostHandshake, PushedImage

log = logging.getLogger("merlion.surface")


class PushPairing:
    """Captures announced, pushes received, and which push is which capture's thumbnail."""

    def __init__(self, ctx: SurfaceContext, sync: GallerySync) -> None:
        self.ctx = ctx
        self.sync = sync
        self.images = ImageReceiver(clock=ctx.clock)
        self._refusal_log = WarningBucket()  # a flood of refused captures is a few lines, not one per message
        self._requests = WarningBucket(REQUEST_BURST, REQUEST_REFILL_S)  # one bucket for every capture asked again

    def on_capture(self, msg) -> None:
        ctx, p = self.ctx, self.ctx.pairing
        try:
            cap = capture_from_message(msg)
        except ValueError as err:  # a dive id that is not a safe name: nothing of it goes near DIR
            if self._refusal_log.take():
                log.warning("capture %d ignored: %s", msg.image_index, err)
            return
        if not self.sync.dive_ok(cap.dive):
            return
        known = ctx.gallery.get(cap.image_index)
        if known is not None and not known.in_summary:
            return  # a re-sent announcement of a frame already trimmed out
        if not ctx.gallery.announce(cap):
            return
        log.info("capture %d at %.1f m", cap.image_index, cap.depth_m or 0.0)
        self.sync.want_index()
        last = p.last_announced
        if last is not None and cap.image_index > last + 1:
            # image indices run without gaps: the captures in between were lost on the way. Their pushes are
            # still coming, in order, so they keep their place in the pairing queue; ask for the captures again.
            for ghost in range(max(last + 1, cap.image_index - 16), cap.image_index):
                if ctx.gallery.get(ghost) is None:
                    log.info("capture %d was lost on the way: asking for it again", ghost)
                    ctx.gallery.announce(Capture(image_index=ghost))
                    self._expect_push(ghost)
                    self._request_capture(ghost)
        p.last_announced = cap.image_index if last is None else max(last, cap.image_index)
        self._expect_push(cap.image_index)

    def on_marker(self, index: int) -> None:
        """MRL_PUSH: the next handshake is this frame's."""
        self.ctx.pairing.marker = index

    def on_handshake(self, msg) -> None:
        self.on_push_result(self.images.handle(msg))
        if msg.size <= 0 or msg.packets <= 0:
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        progress = self.images.in_progress(source)
        if progress is None:
            return
        self._pair_handshake(progress[0], msg.size)
        # a push over the cap is never assembled: its frame (now paired, or when its capture comes) is fetched by FTP
        self.on_push_result(self.images.take_oversized(source))

    def _pair_handshake(self, handshake_no: int, size: int) -> None:
        """The capture this push is for: the one MRL_PUSH named, else the oldest waiting (of matching size)."""
        p = self.ctx.pairing
        marker, p.marker = p.marker, None
        if marker is not None:
            self._bind_marked(handshake_no, marker)
            return
        live = []
        for index, since in p.waiting:
            cap = self.ctx.gallery.get(index)
            if cap is not None and cap.in_summary and cap.thumbnail is None:
                live.append((index, since))
        # the oldest waiting capture whose thumbnail size (from index.json) matches, else the oldest of unknown size
        pick = next((i for i, _ in live if p.expected.get(i) == size), None)
        if pick is None:
            pick = next((i for i, _ in live if i not in p.expected), None)
        p.waiting.clear()
        p.waiting.extend((i, t) for i, t in live if i != pick)
        if pick is None:
            p.early.append(handshake_no)
        else:
            self._bind(handshake_no, pick)

    def on_data(self, msg) -> None:
        """ENCAPSULATED_DATA: one packet of a push."""
        self.on_push_result(self.images.handle(msg))

    def expire(self, now: float) -> None:
        """Give up pushes that stalled, and fetch by FTP the captures no push came for."""
        p = self.ctx.pairing
        for stalled in self.images.expire(self.ctx.options.push_stall_s):
            self.on_push_result(stalled)
        while p.waiting and now - p.waiting[0][1] > self.ctx.options.push_timeout_s:
            index, _ = p.waiting.popleft()
            log.info("no push for capture %d after %.0f s: fetching it by FTP", index,
                     self.ctx.options.push_timeout_s)
            self.sync.fetch_thumbnail(index)

    def _expect_push(self, index: int) -> None:
        p = self.ctx.pairing
        if index in p.bound.values():
            return  # its marked push came first (the capture was lost and asked for again)
        if p.early:
            self._bind(p.early.popleft(), index)
            return
        p.waiting.append((index, self.ctx.clock()))
        if len(p.waiting) > MAX_WAITING:
            # a sender announcing captures without end: the longest waiting is fetched by FTP now, in its turn
            oldest, _ = p.waiting.popleft()
            with self.ctx.lock:
                self.ctx.status.waiting_overflow += 1
                first = self.ctx.status.waiting_overflow == 1
            if first:
                log.warning("more than %d captures wait for their push: the longest waiting are fetched by FTP "
                            "instead (waiting_overflow)", MAX_WAITING)
            self.sync.fetch_thumbnail(oldest)

    def _request_capture(self, index: int) -> None:
        """MAV_CMD_REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED, index): the camera protocol's way to re-get a capture. One
        token bucket bounds them all: each capture jumping ahead asks for up to 16, so without it one datagram of a
        sender without the key became 16 commands on the wire, as often as it liked."""
        ctx = self.ctx
        if ctx.status.companion is None:
            return
        if not self._requests.take():
            with ctx.lock:
                ctx.status.requests_refused += 1
                first = ctx.status.requests_refused == 1
            if first:
                log.warning("more captures to ask for again than %d at once and one every %.0f s: the rest are not "
                            "asked for (their thumbnails still come by push or FTP)", REQUEST_BURST, REQUEST_REFILL_S)
            return
        system, component = ctx.status.companion
        ctx.send(mav.MAVLink_command_long_message(
            system, component, mav.MAV_CMD_REQUEST_MESSAGE, 0,
            mav.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, index, 0, 0, 0, 0, 0))

    def _bind_marked(self, handshake_no: int, index: int) -> None:
        """The handshake the companion named with MRL_PUSH: it is that frame's, whatever arrived in between.
        A frame trimmed meanwhile still gets it (into removed/); one whose capture was lost is asked for again."""
        if self.ctx.gallery.get(index) is None:
            log.info("push for capture %d came before its capture: asking for the capture", index)
            self.ctx.gallery.announce(Capture(image_index=index))
            self._request_capture(index)
        self.ctx.pairing.drop_waiting({index})
        self._bind(handshake_no, index)

    def _bind(self, handshake_no: int, index: int) -> None:
        """A push is capture ``index``'s: stored (or fetched) now if it already ended, else remembered until it
        does. (A push that had ended was remembered too, for good: a sender pushing before each capture grew
        ``bound`` by one a capture.)"""
        p = self.ctx.pairing
        if handshake_no in p.orphans:
            self._store_push(index, p.orphans.pop(handshake_no))
            return
        if handshake_no in p.lost_push:
            self.sync.fetch_thumbnail(index, partial=p.lost_push.pop(handshake_no))
            return
        dropped = p.bind(handshake_no, index)
        if dropped:
            with self.ctx.lock:
                self.ctx.status.bound_dropped += len(dropped)
                first = self.ctx.status.bound_dropped == len(dropped)
            if first:
                log.warning("more than %d pushes paired and still arriving: the oldest pairings are forgotten and "
                            "their frames fetched by FTP (bound_dropped)", MAX_BOUND)
            for lost in dropped:
                self.sync.fetch_thumbnail(lost)

    def on_push_result(self, result: PushedImage | Abandoned | LostHandshake | None) -> None:
        ctx, p = self.ctx, self.ctx.pairing
        if isinstance(result, Abandoned) and result.next_headless:
            result.next_headless = False
            self.on_push_result(result)
            result = LostHandshake(result.source)
        if isinstance(result, LostHandshake):
            # a push whose handshake was lost: it was for the oldest capture still waiting, which must come by FTP
            with ctx.lock:
                ctx.status.pushed_lost += 1
            marker, p.marker = p.marker, None
            if marker is not None:
                log.info("push for capture %d lost its handshake: FTP fallback", marker)
                p.drop_waiting({marker})
                self.sync.fetch_thumbnail(marker)
                return
            while p.waiting:
                index, _ = p.waiting.popleft()
                cap = ctx.gallery.get(index)
                if cap is not None and cap.in_summary and cap.thumbnail is None:
                    log.info("push for capture %d lost its handshake: FTP fallback", index)
                    self.sync.fetch_thumbnail(index)
                    break
        elif isinstance(result, PushedImage):
            index = p.bound.pop(result.handshake_no, None)
            if index is None:
                self._unpaired(p.orphans, result)
            else:
                self._store_push(index, result)
        elif isinstance(result, Abandoned):
            with ctx.lock:
                ctx.status.pushed_lost += 1
            index = p.bound.pop(result.handshake_no, None)
            if result.oversized:
                log.info("push %d of %d bytes is over the %d-byte push cap: FTP fallback", result.handshake_no,
                         result.size, self.images.max_image_bytes)
            else:
                log.info("push %d stalled (%d of %d packets): FTP fallback", result.handshake_no,
                         result.received_packets, result.packets)
            if index is None:
                self._unpaired(p.lost_push, result)
            else:
                self.sync.fetch_thumbnail(index, partial=result)

    def _unpaired(self, pending: dict, push: PushedImage | Abandoned) -> None:
        dropped = self.ctx.pairing.keep_unpaired(pending, push.handshake_no, push)
        if dropped:
            with self.ctx.lock:
                self.ctx.status.unpaired_dropped += dropped
                first = self.ctx.status.unpaired_dropped == dropped
            if first:
                log.warning("more than %d pushes no capture claims: the oldest are dropped (a sender pushing "
                            "images it never announced)", MAX_UNPAIRED)

    def _store_push(self, index: int, image: PushedImage) -> None:
        expected = self.ctx.pairing.expected.get(index)
        if expected is not None and expected != len(image.data):
            log.warning("push of %d bytes paired with capture %d, which has %d: fetching it by FTP instead",
                        len(image.data), index, expected)
            self.sync.fetch_thumbnail(index)
            return
        ext = "jpg" if image.kind == "jpeg" else image.kind
        self.ctx.gallery.add_thumbnail(index, image.data, ext=ext, via="push")
        if expected is None:
            self.sync.want_index()  # the index brings the score, and sizes to pair the next pushes by
        self.sync.verify(index, image.data)
        with self.ctx.lock:
            self.ctx.status.pushed_ok += 1
