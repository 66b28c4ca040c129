"""The gallery role of the surface tool: the summary mirrored from index.json and the status lines, thumbnails
fetched by MAVLink FTP when no push brought them, and every pushed thumbnail checked against the companion's CRC.

It pulls ``/summary/index.json`` when it first meets the companion and after the summary changed, which gives the
score and heading of each frame and mirrors the summary even when a STATUSTEXT was lost. Runs on the receive loop.
"""

from __future__ import annotations

import logging

from companion.topside.ftp_client import crc32_mavftp
from companion.topside.messages import (
    TAKES_BACK,
    index_dive,
    index_topics,
    mftp_path,
    parse_index,
    parse_statustext,
)
from companion.topside.surface_state import (
    FTP_INDEX,
    FTP_THUMBNAILS,
    INDEX_PATH,
    MAX_FETCHES,
    MAX_PARTIAL_BYTES,
    SEVERITY_WARNING,
    SurfaceContext,
)
from vehicle.link.warning_bucket import WarningBucket
from vehicle.protocol.image_push import Abandoned

log = logging.getLogger("merlion.surface")


class GallerySync:
    """Keeps the gallery equal to the companion's summary (index pulls, status lines, FTP fallback, CRC checks)."""

    def __init__(self, ctx: SurfaceContext) -> None:
        self.ctx = ctx
        self._failures = WarningBucket()  # failed thumbnail fetches: a few log lines, then one per 10 s

    # --- the dive and the index ----------------------------------------------------------------------------

    def dive_ok(self, dive: str | None) -> bool:
        """False for a late message of an earlier dive; a new dive (the vehicle's store was reset, image indices
        start again) files the old one away and forgets every pairing made under the old indices."""
        verdict = self.ctx.gallery.use_dive(dive)
        if verdict == "new":
            log.info("dive %s: the vehicle's store was reset; earlier captures filed under dives/", dive)
            self.ctx.pairing.forget_dive()
            self.want_index()
        return verdict != "old"

    def want_index(self) -> None:
        if self.ctx.ftp is None:
            return
        p = self.ctx.pairing
        due = max(self.ctx.clock(), p.index_pulled_at + self.ctx.options.index_refresh_s)
        if p.index_due is None or due < p.index_due:
            p.index_due = due

    def pull_index_when_due(self, now: float) -> None:
        p, ftp = self.ctx.pairing, self.ctx.ftp
        if p.index_due is not None and now >= p.index_due and ftp is not None and INDEX_PATH not in ftp.pending():
            p.index_due = None
            p.index_pulled_at = now
            ftp.fetch(INDEX_PATH, self.on_index, lane=FTP_INDEX)

    def on_index(self, _path: str, data: bytes | None, error: str) -> None:
        ctx, p = self.ctx, self.ctx.pairing
        if data is None:
            log.warning("FTP %s: %s", INDEX_PATH, error)
            with ctx.lock:
                ctx.status.ftp_failed += 1
            return
        try:
            captures = parse_index(data)
            dive = index_dive(data)
            topics = index_topics(data)
        except (ValueError, TypeError, OverflowError, AttributeError) as err:
            # not JSON, a dive id that is not a safe name, or values of the wrong kind ({"image_index": [1]},
            # 1e400): one line, not the traceback the FTP client logs for a callback that raised
            log.warning("%s ignored: %s", INDEX_PATH, err)
            return
        if not self.dive_ok(dive):
            return  # asked for before the store was reset: it lists the earlier dive
        with ctx.lock:
            ctx.status.index_pulls += 1
            ctx.status.ftp_ok += 1
        if topics is not None:
            ctx.gallery.set_topics(topics)
        asked = ctx.ftp.started_wall if ctx.ftp is not None else None
        gone = set(ctx.gallery.mirror([c.image_index for c in captures], announced_before=asked))
        # frames that left without a push keep no place in the pairing queue (else every later push shifts)
        p.drop_waiting(gone)
        waiting = {i for i, _ in p.waiting}
        p.expected.clear()  # of the frames this index lists: a frame it does not list has left the summary
        p.crc.clear()
        for cap in captures:
            if (cap.file_url or "").endswith(".jpg"):  # pushes are JPEG: comparable
                if cap.thumbnail_bytes is not None:
                    p.expected[cap.image_index] = cap.thumbnail_bytes
                if cap.thumbnail_crc32 is not None:
                    p.crc[cap.image_index] = cap.thumbnail_crc32
            tags = {k: getattr(cap, k) for k in ("time_utc", "depth_m", "heading_deg", "q", "lat", "lon", "alt_m",
                                                 "score", "raw_score", "topic", "file_url", "thumbnail_crc32",
                                                 "below_threshold")}
            ctx.gallery.update_tags(cap.image_index, **tags)
            known = ctx.gallery.get(cap.image_index)
            if known is None:
                continue
            if (known.thumbnail is not None and known.thumbnail_via == "push" and cap.thumbnail_bytes is not None
                    and known.thumbnail_bytes != cap.thumbnail_bytes):
                # the push paired with this capture was another frame's (a thumbnail dropped unannounced):
                # fetch the right one by name
                log.warning("capture %d: pushed thumbnail has %d bytes, the companion says %d: re-fetching",
                            cap.image_index, known.thumbnail_bytes, cap.thumbnail_bytes)
                p.unverified.pop(cap.image_index, None)
                self.fetch_thumbnail(cap.image_index, replace=True)
                continue
            if known.thumbnail is not None:
                continue
            # a frame we never heard announced has no push coming: fetch it now
            if cap.image_index not in waiting and cap.image_index not in p.bound.values():
                self.fetch_thumbnail(cap.image_index)
        self._verify_waiting({c.image_index for c in captures})

    # --- status lines --------------------------------------------------------------------------------------

    def on_statustext(self, msg, now: float) -> None:
        ctx = self.ctx
        text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else msg.text
        text = text.rstrip("\0")
        with ctx.lock:
            line = {"time": now, "severity": int(msg.severity), "text": text}
            cleared = TAKES_BACK.get(text)
            if cleared is not None:  # the condition is over: the page no longer shows it as if it held
                for lines in (ctx.status.statustext, ctx.status.warnings):
                    kept = [old for old in lines if old["text"] != cleared]
                    if len(kept) != len(lines):
                        lines.clear()
                        lines.extend(kept)
            ctx.status.statustext.append(line)
            if line["severity"] <= SEVERITY_WARNING:
                ctx.status.warnings.append(line)
        facts = parse_statustext(text)
        for index in facts.removed:
            if ctx.gallery.remove(index):
                log.info("capture %d trimmed out of the summary", index)
            ctx.pairing.drop_waiting({index})
        for index, score in facts.scores.items():
            ctx.gallery.update_tags(index, score=score)
        for index, topic in facts.topics.items():
            ctx.gallery.update_tags(index, topic=topic)
        if facts.removed or facts.summary_changed or facts.added:
            self.want_index()

    # --- thumbnails by FTP and their checks ----------------------------------------------------------------

    def verify(self, index: int, data: bytes) -> None:
        """A push may be paired by order, and a salvaged one is part push: check the bytes against the CRC32 that
        index.json gives for the companion's file (no extra request; a push usually lands before the index that
        lists it, so the check waits for that pull); on a mismatch fetch the whole file by name."""
        cap = self.ctx.gallery.get(index)
        path = mftp_path((cap.file_url if cap else None) or "") or f"/summary/{index}.jpg"
        if self.ctx.ftp is None or not path.endswith(".jpg"):
            return  # a WebP thumbnail on the server is not the JPEG that was pushed: nothing to compare
        self._verify_crc(index, crc32_mavftp(data))

    def _verify_crc(self, index: int, got: int) -> None:
        """``got``: the CRC-32 of the thumbnail we hold for ``index``."""
        crc = self.ctx.pairing.crc.get(index)
        if crc is None:
            self.ctx.pairing.unverified[index] = got
            self.want_index()
            return
        self.ctx.pairing.unverified.pop(index, None)
        self._checked(index, crc == got)

    def _checked(self, index: int, ok: bool) -> None:
        with self.ctx.lock:
            if ok:
                self.ctx.status.verified += 1
                return
            self.ctx.status.mismatched += 1
        log.warning("thumbnail of capture %d is not the companion's (CRC differs): fetching it by name", index)
        self.fetch_thumbnail(index, replace=True)

    def _verify_by_request(self, index: int, got: int) -> None:
        """The fallback for a companion whose index.json has no CRC: one CalcFileCRC32 request."""
        cap = self.ctx.gallery.get(index)
        path = mftp_path((cap.file_url if cap else None) or "") or f"/summary/{index}.jpg"
        if self.ctx.ftp is None:
            return

        def checked(_path: str, crc: int | None, error: str) -> None:
            if crc is None:
                log.debug("CRC of %s: %s", path, error)  # e.g. trimmed meanwhile: nothing to fix
                return
            self._checked(index, crc == got)

        self.ctx.ftp.crc(path, checked, lane=FTP_THUMBNAILS)

    def _verify_waiting(self, listed: set[int]) -> None:
        """After an index pull: check the pushes that waited for their CRC; an index without CRCs (another
        companion) gets the CalcFileCRC32 request instead; frames trimmed meanwhile need no check."""
        p = self.ctx.pairing
        for index, got in list(p.unverified.items()):
            cap = self.ctx.gallery.get(index)
            if cap is None or not cap.in_summary:
                del p.unverified[index]
            elif index in p.crc:
                self._verify_crc(index, got)
            elif index in listed:
                del p.unverified[index]
                self._verify_by_request(index, got)
            # else: announced after this index was built; the next pull lists it

    def fetch_thumbnail(self, index: int, *, replace: bool = False, partial: Abandoned | None = None) -> None:
        """Queue an FTP pull of the thumbnail (with the ``partial`` push it came from: only the packets the push
        lost). The queue holds one entry per frame, fetched one at a time in the order asked for (``pump``)."""
        ctx, p = self.ctx, self.ctx.pairing
        cap = ctx.gallery.get(index)
        if ctx.ftp is None or cap is None or not cap.in_summary or (ctx.gallery.dive, index) in p.fetching:
            return
        if cap.thumbnail is not None and not replace:
            return
        old = p.fetch_queue.pop(index, None)
        if old is not None:
            replace, partial = replace or old[0], partial or old[1]
            p.partial_bytes -= _held(old[1])
        if partial is not None and p.partial_bytes + _held(partial) > MAX_PARTIAL_BYTES:
            partial = None  # read the whole file: stalled pushes by the megabyte are not kept for the queue
        p.partial_bytes += _held(partial)
        p.fetch_queue[index] = (replace, partial)
        dropped = 0
        while len(p.fetch_queue) > MAX_FETCHES:
            _, (_, gone) = p.fetch_queue.popitem(last=False)
            p.partial_bytes -= _held(gone)
            dropped += 1
        if dropped:
            with ctx.lock:
                ctx.status.fetches_dropped += dropped
                first = ctx.status.fetches_dropped == dropped
            if first:
                log.warning("more than %d thumbnails wait for FTP: the longest waiting are forgotten "
                            "(fetches_dropped)", MAX_FETCHES)
        self.pump()

    def pump(self) -> None:
        """Hand the FTP client the next thumbnail waiting, when none of ours is in its queue: the index pulls and
        the page's requests take their turns between thumbnails, however many wait."""
        ctx, p = self.ctx, self.ctx.pairing
        while ctx.ftp is not None and p.fetch_queue and not ctx.ftp.pending(FTP_THUMBNAILS):
            index, (replace, partial) = p.fetch_queue.popitem(last=False)
            p.partial_bytes -= _held(partial)
            self._start_fetch(index, replace, partial)

    def _start_fetch(self, index: int, replace: bool, partial: Abandoned | None) -> None:
        ctx = self.ctx
        cap = ctx.gallery.get(index)
        dive = ctx.gallery.dive
        if cap is None or not cap.in_summary or (dive, index) in ctx.pairing.fetching:
            return  # trimmed (or forgotten) while it waited
        if cap.thumbnail is not None and not replace:
            return  # its push came meanwhile
        assert ctx.ftp is not None
        path = mftp_path(cap.file_url or "") or f"/summary/{index}.jpg"
        ctx.pairing.fetching.add((dive, index))

        def done(_path: str, data: bytes | None, error: str) -> None:
            ctx.pairing.fetching.discard((dive, index))
            with ctx.lock:
                if data is None:
                    ctx.status.ftp_failed += 1
                else:
                    ctx.status.ftp_ok += 1
            try:
                if data is None:
                    if self._failures.take():  # a sender announcing frames it has not: a few lines, not one each
                        log.warning("FTP %s: %s", path, error)
                    return
                if ctx.gallery.dive != dive:
                    return  # the vehicle's store was reset meanwhile: this index now names another frame
                now_cap = ctx.gallery.get(index)
                if now_cap is not None and (replace or now_cap.thumbnail is None):
                    ext = path.rsplit(".", 1)[-1] if "." in path.rsplit("/", 1)[-1] else "jpg"
                    ctx.gallery.add_thumbnail(index, data, ext=ext, via="push+ftp" if known else "ftp")
                    if known:
                        self.verify(index, data)
            finally:
                self.pump()

        known, known_size = {}, None
        if partial is not None and partial.kind == "jpeg" and path.endswith(".jpg"):
            known, known_size = partial.chunks, partial.size  # the same JPEG file: fill in only the holes
        ctx.ftp.fetch(path, done, known=known, known_size=known_size, lane=FTP_THUMBNAILS)


def _held(partial: Abandoned | None) -> int:
    """Bytes a partial push keeps in memory."""
    return 0 if partial is None else sum(len(chunk) for chunk in partial.chunks.values())
