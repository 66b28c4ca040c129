"""The MAVLink image transmission protocol, both halves, written once: framing on the vehicle, reassembly topside.

One DATA_TRANSMISSION_HANDSHAKE (130) announces type, size, width, height, packet count, payload per packet and
JPEG quality; ENCAPSULATED_DATA (131) follows with ``seqnr`` 0..packets-1, chunk ``seqnr`` holding bytes
``seqnr * 253`` onwards (the last one zero padded; MAVLink 2 trims the trailing zeros on the wire).

``ImageReceiver`` follows QGroundControl's reading of the protocol so that what the surface tool, the benchmarks
and the tests receive is what the operator's ground station receives: a handshake starts a new image, chunk
``seqnr`` is written at ``seqnr * payload``, the image is complete when every packet has arrived, and a lost
packet leaves the image stalled until the next handshake (which abandons it; the caller then fetches that image
another way).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mav

CHUNK = 253
"""ENCAPSULATED_DATA.data length."""
MAX_PUSH_BYTES = 2 * 1024 * 1024
"""The largest image ``ImageReceiver`` assembles in memory: a thumbnail is kilobytes, while a handshake may announce
up to 65,535 packets of 255 bytes (16.7 MB), a buffer allocated before one packet arrived. A larger push is
ignored and reported as abandoned, so the caller fetches that image another way (FTP)."""
TYPE_JPEG = mav.MAVLINK_DATA_STREAM_IMG_JPEG


def push_messages(data: bytes, width: int, height: int, quality: int, *,
                  image_type: int = TYPE_JPEG) -> list[mav.MAVLink_message]:
    """Handshake then every chunk of ``data``: the whole image as the receiver needs it, in order."""
    if not data:
        raise ValueError("cannot push an empty image")
    packets = (len(data) + CHUNK - 1) // CHUNK
    if packets > 0xFFFF:
        raise ValueError(f"image of {len(data)} bytes needs {packets} packets, more than 65535")
    msgs: list[mav.MAVLink_message] = [mav.MAVLink_data_transmission_handshake_message(
        image_type, len(data), width, height, packets, CHUNK, max(0, min(100, quality)))]
    for seq in range(packets):
        chunk = data[seq * CHUNK:(seq + 1) * CHUNK]
        msgs.append(mav.MAVLink_encapsulated_data_message(seq, list(chunk.ljust(CHUNK, b"\0"))))
    return msgs


IMAGE_TYPES = {0: "jpeg", 1: "bmp", 2: "raw8u", 3: "raw32u", 4: "pgm", 5: "png"}
"""MAVLINK_DATA_STREAM_TYPE values, as file-name extensions."""


@dataclass
class PushedImage:
    """One image the sender pushed, complete and trimmed to the size its handshake announced."""

    data: bytes
    kind: str
    width: int
    height: int
    source: tuple[int, int]
    """(system, component) of the sender."""
    started: float
    finished: float
    handshake_no: int
    """Counts handshakes from this source, so callers can order pushes and spot abandoned ones."""


@dataclass
class _Transfer:
    size: int
    packets: int
    payload: int
    kind: str
    width: int
    height: int
    started: float
    handshake_no: int
    last_progress: float = 0.0
    buffer: bytearray = field(default_factory=bytearray)
    received: set[int] = field(default_factory=set)
    oversized: bool = False
    """Over the receiver's cap: no buffer, its packets ignored (``take_oversized``)."""

    def abandoned(self, source: tuple[int, int]) -> Abandoned:
        chunks = {}
        for seq in sorted(self.received):
            start = seq * self.payload
            piece = bytes(self.buffer[start : min(start + self.payload, self.size)])
            if piece:
                chunks[start] = piece
        return Abandoned(source, self.handshake_no, len(self.received), self.packets, self.size, self.kind, chunks,
                         oversized=self.oversized)


@dataclass
class Abandoned:
    """An image whose handshake came but whose packets never all arrived before the next handshake."""

    source: tuple[int, int]
    handshake_no: int
    received_packets: int
    packets: int
    size: int = 0
    kind: str = "jpeg"
    chunks: dict[int, bytes] = field(default_factory=dict)
    """What did arrive, by byte offset: a pull of the same file needs only the rest."""
    next_headless: bool = False
    """The next image's packets came without its handshake (so that image is lost too)."""
    oversized: bool = False
    """Never assembled: its handshake announced more than the receiver's cap."""


@dataclass
class LostHandshake:
    """Packets of a new image arrived without its handshake: that image cannot be reassembled at all."""

    source: tuple[int, int]


class ImageReceiver:
    """Feeds on MAVLink messages; ``handle`` returns a finished image, an abandoned transfer, or None."""

    def __init__(self, clock=time.monotonic, max_image_bytes: int = MAX_PUSH_BYTES) -> None:
        self._clock = clock
        self.max_image_bytes = max_image_bytes
        self._transfers: dict[tuple[int, int], _Transfer] = {}
        self._handshakes: dict[tuple[int, int], int] = {}
        self._headless: set[tuple[int, int]] = set()  # sources sending packets of an image we saw no handshake of
        self.completed = 0
        self.abandoned = 0
        self.oversized = 0
        """Handshakes over ``max_image_bytes``: not assembled."""
        self.bytes_received = 0

    def feed(self, msg) -> bytes | None:
        """The image bytes when ``msg`` completes one (for callers that need nothing else)."""
        got = self.handle(msg)
        return got.data if isinstance(got, PushedImage) else None

    def handle(self, msg) -> PushedImage | Abandoned | LostHandshake | None:
        """Process one message (others are ignored); say what, if anything, it finished or abandoned."""
        kind = msg.get_type()
        if kind == "DATA_TRANSMISSION_HANDSHAKE":
            return self._handshake(msg)
        if kind == "ENCAPSULATED_DATA":
            return self._chunk(msg)
        return None

    def in_progress(self, source: tuple[int, int]) -> tuple[int, int, int] | None:
        """(handshake number, packets received, packets expected) of the image arriving from ``source``."""
        t = self._transfers.get(source)
        return None if t is None else (t.handshake_no, len(t.received), t.packets)

    def take_oversized(self, source: tuple[int, int]) -> Abandoned | None:
        """The push arriving from ``source`` when its handshake was over the cap: given up now (its packets are
        ignored until the next handshake), so the caller can fetch the image another way at once."""
        t = self._transfers.get(source)
        if t is None or not t.oversized:
            return None
        del self._transfers[source]
        self._headless.add(source)  # its packets are no next image whose handshake was lost
        self.abandoned += 1
        return t.abandoned(source)

    def expire(self, idle_s: float) -> list[Abandoned]:
        """Give up on images that made no progress for ``idle_s``, or for four times the usual gap between
        their packets on a slow link: the last push of a burst of summary changes has no next handshake to
        abandon it, and its frame should not wait for one."""
        now = self._clock()
        gone = []
        for source, t in list(self._transfers.items()):
            arrived = len(t.received)
            usual_gap = (t.last_progress - t.started) / arrived if arrived else 0.0
            if now - t.last_progress > max(idle_s, 4.0 * usual_gap):
                del self._transfers[source]
                self.abandoned += 1
                gone.append(t.abandoned(source))
        return gone

    def _handshake(self, msg) -> Abandoned | None:
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        self._headless.discard(source)
        previous = self._transfers.pop(source, None)
        gone = None
        if previous is not None and len(previous.received) < previous.packets:
            self.abandoned += 1
            gone = previous.abandoned(source)
        # A handshake with nothing to send (size or packets 0) is how some senders answer a request: no image.
        if msg.size <= 0 or msg.packets <= 0 or msg.payload <= 0:
            return gone
        if msg.packets * msg.payload < msg.size:
            return gone  # cannot hold the announced size: not a transfer we can reassemble
        number = self._handshakes.get(source, 0) + 1
        self._handshakes[source] = number
        oversized = msg.size > self.max_image_bytes or msg.packets * msg.payload > self.max_image_bytes + msg.payload
        self.oversized += oversized
        self._transfers[source] = _Transfer(
            size=msg.size, packets=msg.packets, payload=msg.payload, kind=IMAGE_TYPES.get(msg.type, "bin"),
            width=msg.width, height=msg.height, started=self._clock(), handshake_no=number,
            last_progress=self._clock(),
            buffer=bytearray(0 if oversized else msg.packets * msg.payload), oversized=oversized,
        )
        return gone

    def _chunk(self, msg) -> PushedImage | Abandoned | LostHandshake | None:
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        t = self._transfers.get(source)
        if t is None:
            # the first packets of an image with no handshake before them: its handshake was lost
            if msg.seqnr <= 1 and source not in self._headless:
                self._headless.add(source)
                self.abandoned += 1
                return LostHandshake(source)
            return None
        if t.oversized or not 0 <= msg.seqnr < t.packets:
            return None
        if msg.seqnr <= 1 and t.received and max(t.received) > msg.seqnr + 1:
            # packets start again from the top (MAVLink links keep their order): the next image began and its
            # handshake was lost. Mixing its packets into this one would make a picture of neither.
            del self._transfers[source]
            self._headless.add(source)
            self.abandoned += 2
            gone = t.abandoned(source)
            gone.next_headless = True
            return gone
        start = msg.seqnr * t.payload
        data = bytes(msg.data)[: t.payload]
        t.buffer[start : start + len(data)] = data
        if msg.seqnr not in t.received:
            t.received.add(msg.seqnr)
            t.last_progress = self._clock()
            self.bytes_received += len(data)
        if len(t.received) < t.packets:
            return None
        del self._transfers[source]
        self.completed += 1
        return PushedImage(
            data=bytes(t.buffer[: t.size]), kind=t.kind, width=t.width, height=t.height, source=source,
            started=t.started, finished=self._clock(), handshake_no=t.handshake_no,
        )
