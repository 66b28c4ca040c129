"""What the surface tool's roles share: its options, the link status the page shows, and the pairing state.

The roles (``tool.SurfaceTool``: the link; ``gallery_sync``: index, status lines, FTP fallback and checks;
``push_pairing``: captures paired with pushed thumbnails; ``page_state``: what the page shows; ``actions``: what
the page asks for) run on the receive loop, except the page's reads and requests, which take ``lock`` or queue
their work on ``requests`` for the loop. Each role gets this one explicit ``SurfaceContext``.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field

from companion.topside.ftp_client import FtpClient
from companion.topside.gallery import Gallery
from vehicle.protocol.image_push import Abandoned, PushedImage

INDEX_PATH = "/summary/index.json"
PUSH_MARKER = "MRL_PUSH"
DEPTH_VALUE = "MRL_DEPTH"
SEVERITY_WARNING = 4
FULL_FRAME_TIMEOUT_S = 120.0
"""A full frame (tens of kB) at a 2,000 B/s budget, sent after everything else: give it time."""
MARKS_TIMEOUT_S = 30.0
"""A marks upload is a few hundred bytes: a page's request waits this long for the companion's answer."""
OFFLINE_EVERY_S = 2.0
MAX_UNPAIRED = 16
"""Pushes kept while no capture claims them (finished or abandoned): the companion announces a frame before it
pushes it, so a handful covers a reordering; more are a sender pushing images nobody announced, which grew without
bound (each up to the push cap). The oldest go first, as ``early`` handshakes do."""

MAX_BOUND = MAX_UNPAIRED
"""Pushes paired with a capture and still arriving (``PairingState.bound``). The companion pushes one image at a
time and a handshake is paired once, so one or two are bound at once; as for pushes no capture claims, 16 cover
any reordering. Past it the oldest pairing is forgotten and its capture fetched by FTP (its push, should it
finish, then waits unpaired)."""

MAX_WAITING = 256
"""Captures waiting for their push at once. The companion pushes each frame right after announcing it, so a few wait
(a summary filling up at a dive's start, a few dozen); a sender announcing captures without end made the queue
grow for good. Past this, the capture that waited longest stops waiting and is fetched by FTP (its turn in the
FTP queue), as if its push had timed out."""
MAX_FETCHES = 8192
"""Thumbnails waiting for their FTP fetch (one per frame of the summary at most, ``gallery.MAX_SUMMARY``); they are
fetched one at a time, in the order asked for, so the index pulls and the page's requests take their turns
between them. Past this the longest waiting is forgotten (``fetches_dropped``; the next index.json lists it
again while it is in the summary)."""
MAX_PARTIAL_BYTES = 4 << 20
"""Bytes of stalled pushes kept for the FTP fetches that wait (only their holes are read); past this a waiting
fetch reads the whole file instead (a push may be 2 MiB: a queue of them was gigabytes)."""
FTP_INDEX, FTP_THUMBNAILS, FTP_PAGE = "index", "thumbnails", "page"
"""The FTP client's lanes: each requester's requests wait apart and are served in turn."""

REQUEST_BURST = 16
REQUEST_REFILL_S = 1.0
"""Captures asked for again (MAV_CMD_REQUEST_MESSAGE): 16 at once (the most one jump asks for), then one a second,
for all of them together. A real gap is a few captures lost on a lossy link; more is a sender making the tool talk."""


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
    gallery_write_every_s: float = 0.25
    """gallery.json is rewritten at most this often (the last state always; log.csv gets every event at once)."""
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
    foreign_autopilot_heartbeats: int = 0
    """Autopilot heartbeats from another system or component than the first autopilot: ignored."""
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
    """Gaps in the sequence numbers of the autopilot's and the companion's messages (no other source's), from the
    address each was first heard at (without a key)."""
    other_address_messages: int = 0
    """Without a key: messages under the autopilot's or the companion's ids from another address than theirs (their
    sequence numbers not followed)."""
    unsigned_ignored: int = 0
    """With a signing key: messages not verified as the companion's (unsigned, badly signed, replayed) ignored."""
    unsigned_sources: dict[tuple[int, int], int] = field(default_factory=dict)
    inbox_dropped: int = 0
    """Messages dropped because the receive loop was ``tool.INBOX_MAX`` behind."""
    values_dropped: int = 0
    """Values under a new name once ``tool.MAX_VALUES`` names are shown: ignored."""
    requests_refused: int = 0
    """Lost captures not asked for again: past ``REQUEST_BURST`` at once, one every ``REQUEST_REFILL_S``."""
    unpaired_dropped: int = 0
    """Pushes no capture claimed, dropped beyond ``MAX_UNPAIRED``."""
    waiting_overflow: int = 0
    """Captures that stopped waiting for a push beyond ``MAX_WAITING`` (fetched by FTP instead)."""
    fetches_dropped: int = 0
    """Thumbnail fetches forgotten beyond ``MAX_FETCHES`` waiting."""
    bound_dropped: int = 0
    """Pairings of a push still arriving with its capture forgotten beyond ``MAX_BOUND`` (fetched by FTP)."""


@dataclass
class PairingState:
    """What the loop remembers between messages about captures, pushes and index pulls of the current dive."""

    waiting: deque = field(default_factory=deque)
    """Captures waiting for a push: (image index, since)."""
    early: deque = field(default_factory=lambda: deque(maxlen=MAX_UNPAIRED))
    """Handshakes that came before their capture (their numbers)."""
    expected: dict[int, int] = field(default_factory=dict)
    """Thumbnail bytes by image index, from the latest index.json (JPEG only)."""
    bound: dict[int, int] = field(default_factory=dict)
    """Handshake number -> image index, for pushes still arriving (``MAX_BOUND`` at most, see ``bind``)."""
    orphans: dict[int, PushedImage] = field(default_factory=dict)
    """Finished pushes not yet paired."""
    lost_push: dict[int, Abandoned] = field(default_factory=dict)
    """Pushes abandoned before pairing, by handshake number."""
    fetching: set[tuple[str | None, int]] = field(default_factory=set)
    """(dive, image index) being pulled by FTP."""
    fetch_queue: OrderedDict = field(default_factory=OrderedDict)
    """Thumbnails of the current dive waiting for their FTP fetch: image index -> (replace, partial push or None),
    in the order asked for (``MAX_FETCHES`` at most)."""
    partial_bytes: int = 0
    """Bytes of the partial pushes in ``fetch_queue`` (``MAX_PARTIAL_BYTES`` at most)."""
    marker: int | None = None
    """Image index named by the last MRL_PUSH, until its handshake comes."""
    crc: dict[int, int] = field(default_factory=dict)
    """Thumbnail CRC32 by image index, from the latest index.json (JPEG only): each pull replaces them, so indices
    listed once never pile up."""
    unverified: dict[int, int] = field(default_factory=dict)
    """CRC-32s of pushed thumbnails waiting for an index.json with the companion's (the CRC, not the bytes: a push
    may be 2 MiB, and one waits per frame of the summary)."""
    last_announced: int | None = None
    index_due: float | None = None
    index_pulled_at: float = -1e9

    def forget_dive(self) -> None:
        """A new dive: image indices start again, so every pairing made under the old ones goes."""
        for pending in (self.waiting, self.early, self.expected, self.bound, self.orphans, self.lost_push, self.crc,
                        self.unverified, self.fetch_queue):
            pending.clear()
        self.partial_bytes = 0
        self.last_announced = None

    def keep_unpaired(self, pending: dict, handshake_no: int, push) -> int:
        """Keep a push no capture claims yet in ``pending`` (``orphans`` or ``lost_push``), the oldest going when
        there are more than ``MAX_UNPAIRED``; how many went."""
        pending[handshake_no] = push
        dropped = 0
        while len(pending) > MAX_UNPAIRED:
            del pending[next(iter(pending))]
            dropped += 1
        return dropped

    def bind(self, handshake_no: int, index: int) -> list[int]:
        """Remember that the push ``handshake_no``, still arriving, is capture ``index``'s; past ``MAX_BOUND``
        the oldest pairings are forgotten: their image indices, for the caller to fetch by FTP."""
        self.bound[handshake_no] = index
        dropped = []
        while len(self.bound) > MAX_BOUND:
            oldest = next(iter(self.bound))
            dropped.append(self.bound.pop(oldest))
        return dropped

    def drop_waiting(self, gone) -> None:
        """Take the captures in ``gone`` (a container of image indices) out of the pairing queue."""
        self.waiting = deque((i, t) for i, t in self.waiting if i not in gone)


@dataclass
class SurfaceContext:
    """The one explicit context every role of the surface tool is built with."""

    options: SurfaceOptions
    gallery: Gallery
    clock: Callable[[], float]
    send: Callable[[object], object]
    """Send a MAVLink message on the tool's one connection."""
    status: LinkStatus = field(default_factory=LinkStatus)
    lock: threading.Lock = field(default_factory=threading.Lock)
    pairing: PairingState = field(default_factory=PairingState)
    requests: queue.Queue = field(default_factory=queue.Queue)
    """Work handed to the receive loop by other threads (the web server's)."""
    ftp: FtpClient | None = None
    """The FTP client to the companion, once it is found (owned by the receive loop)."""
    marks: dict[str, list[int]] = field(default_factory=lambda: {"like": [], "unlike": []})
    """The marks this tool last had accepted by the companion (the page shows them on the cards)."""
