"""The actions role of the surface tool: what the page asks of the companion (a full frame, the operator's marks).

Called from the web server's threads; the work itself is queued for the receive loop, which owns the FTP client,
and the caller waits for its result with a timeout.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from companion.topside.marks_upload import MARKS_PATH, marks_document
from companion.topside.surface_state import FTP_PAGE, FULL_FRAME_TIMEOUT_S, MARKS_TIMEOUT_S, SurfaceContext

log = logging.getLogger("merlion.surface")


class SurfaceActions:
    """Full frames on demand and the operator's marks."""

    def __init__(self, ctx: SurfaceContext) -> None:
        self.ctx = ctx

    def full_frame(self, index: int, timeout: float = FULL_FRAME_TIMEOUT_S) -> Path | None:
        """The full-resolution frame of a summary frame of the current dive, fetched by FTP
        (``/summary/full/<n>.jpg``) the first time it is asked for and kept in DIR/full/; None when the companion
        no longer has it or the link did not deliver it in time."""
        ctx = self.ctx
        dive = ctx.gallery.dive
        cached = ctx.gallery.full_path(index, dive)
        if cached.is_file():
            return cached
        done = threading.Event()
        result: list[Path | None] = [None]

        def start() -> None:
            cap = ctx.gallery.get(index)
            if ctx.ftp is None or cap is None or not cap.in_summary or ctx.gallery.dive != dive:
                done.set()
                return

            def fetched(_path: str, data: bytes | None, error: str) -> None:
                if data and ctx.gallery.dive == dive:
                    result[0] = ctx.gallery.add_full(index, data, dive)
                else:
                    log.info("full frame %d: %s", index, error or "not fetched")
                done.set()

            ctx.ftp.fetch(f"/summary/full/{index}.jpg", fetched, lane=FTP_PAGE)

        ctx.requests.put(start)
        done.wait(timeout)
        return result[0]

    def mark(self, index: int, kind: str, timeout: float = MARKS_TIMEOUT_S) -> str:
        """The page's button: mark frame ``index`` "like", "unlike" or "none" (unmark), on top of the marks this
        tool sent before, and send the whole set; returns "" once the companion took it, else why not."""
        if kind not in ("like", "unlike", "none"):
            raise ValueError(f"mark {kind!r}: expected like, unlike or none")
        ctx = self.ctx
        with ctx.lock:
            like = [i for i in ctx.marks["like"] if i != index] + ([index] if kind == "like" else [])
            unlike = [i for i in ctx.marks["unlike"] if i != index] + ([index] if kind == "unlike" else [])
        error = self.send_marks(like, unlike, timeout)
        if not error:
            with ctx.lock:
                ctx.marks = {"like": like, "unlike": unlike}
        return error

    def send_marks(self, like: list[int], unlike: list[int], timeout: float = MARKS_TIMEOUT_S) -> str:
        """Upload ``/config/marks.json`` (image indices "more like this" / "not this") to the companion; returns
        "" once it accepted them, else why not."""
        ctx = self.ctx
        data = marks_document(like, unlike)  # ValueError: malformed, as the companion would refuse it
        done = threading.Event()
        result = ["no answer from the companion"]

        def start() -> None:
            if ctx.ftp is None:
                result[0] = "no companion yet (or --no-ftp)"
                done.set()
                return

            def sent(_path: str, got: bytes | None, error: str) -> None:
                result[0] = "" if got is not None else (error or "not sent")
                done.set()

            ctx.ftp.upload(MARKS_PATH, data, sent, lane=FTP_PAGE)

        ctx.requests.put(start)
        done.wait(timeout)
        if not result[0]:
            log.info("marks sent: like %s, unlike %s", like, unlike)
        return result[0]


def page_mark(actions: SurfaceActions, index: object, kind: object) -> dict:
    """What the page's "more like this" / "not this" button posts, checked, sent, and answered with the marks now
    held; a bad index, a refusal or no answer from the companion is a ValueError (the page shows its message).
    Shared by `merlion surface` and the BlueOS extension, which serve the same button."""
    if not isinstance(index, int) or isinstance(index, bool) or index < 0:
        raise ValueError(f"mark: index {index!r} is not an image index")
    error = actions.mark(index, str(kind))
    if error:
        raise ValueError(f"marks not set: {error}")
    with actions.ctx.lock:
        return {"marks": {k: list(v) for k, v in actions.ctx.marks.items()}}

