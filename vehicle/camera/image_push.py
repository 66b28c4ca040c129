"""Push a thumbnail with the MAVLink image transmission protocol, as QGroundControl reassembles it.

One DATA_TRANSMISSION_HANDSHAKE (130) announces type, size, width, height, packet count, payload per packet and
JPEG quality; ENCAPSULATED_DATA (131) follows with ``seqnr`` 0..packets-1, chunk ``seqnr`` holding bytes
``seqnr * 253`` onwards (the last one zero padded; MAVLink 2 trims the trailing zeros on the wire).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

CHUNK = 253
"""ENCAPSULATED_DATA.data length."""
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


class PushReassembler:
    """The receiving half (QGroundControl's logic): write chunks at ``seqnr * payload``, done when all came.

    Lives here beside the sender so that the benchmark and tests check the sender against the same rules a ground
    station applies; a lost chunk stalls the image until the next handshake replaces it.
    """

    def __init__(self) -> None:
        self.handshake: mav.MAVLink_data_transmission_handshake_message | None = None
        self._chunks: dict[int, bytes] = {}
        self.completed: list[bytes] = []

    def feed(self, msg: mav.MAVLink_message) -> bytes | None:
        """Returns the image when ``msg`` completes one."""
        kind = msg.get_type()
        if kind == "DATA_TRANSMISSION_HANDSHAKE":
            if msg.packets == 0:
                return None
            self.handshake = msg
            self._chunks = {}
            return None
        if kind != "ENCAPSULATED_DATA" or self.handshake is None:
            return None
        hs = self.handshake
        if msg.seqnr >= hs.packets:
            return None
        self._chunks[msg.seqnr] = bytes(msg.data)
        if len(self._chunks) < hs.packets:
            return None
        blob = b"".join(self._chunks[i][: hs.payload] for i in range(hs.packets))[: hs.size]
        self.handshake = None
        self._chunks = {}
        self.completed.append(blob)
        return blob
