"""Peers on the tether for the hostile-peer tests: a signed autopilot, signed ground stations and unsigned attackers.

Each peer is a plain UDP socket on 127.0.0.1 packing real pymavlink MAVLink 2 messages with its own encoder (signed
with a key or not), sending to the companion's ``udpin`` port and collecting what comes back on a thread.
"""

from __future__ import annotations

import hashlib
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mav2

from vehicle.link.signing import now_timestamp

PASSPHRASE = "reef survey 17"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()


class Peer:
    """One MAVLink endpoint on its own socket: ``send`` packs with its ids (signed when ``key``), a thread reads."""

    def __init__(self, port: int, system: int, component: int, key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.addr = ("127.0.0.1", port)
        self.mav = mav2.MAVLink(None, srcSystem=system, srcComponent=component)
        if key is not None:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = key, True
            self.mav.signing.timestamp = now_timestamp()
        self.ids = (system, component)
        self._parser = mav2.MAVLink(None)
        self._parser.robust_parsing = True
        self._lock = threading.Lock()
        self.received: list[mav2.MAVLink_message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def send(self, msg: mav2.MAVLink_message) -> bytes:
        with self._lock:
            packet = msg.pack(self.mav)
            self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(packet, self.addr)
        return packet

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(4096)
            except (TimeoutError, BlockingIOError):
                continue
            except OSError:
                return
            msgs = self._parser.parse_buffer(data) or []
            with self._lock:
                self.received.extend(msgs)

    def got(self, kind: str, src: tuple[int, int] | None = None, cond=None) -> list:
        """Messages of ``kind`` received so far (from ``src``, satisfying ``cond``), addressed to anyone."""
        with self._lock:
            msgs = list(self.received)
        return [m for m in msgs if m.get_type() == kind and (src is None or (m.get_srcSystem(),
                                                                            m.get_srcComponent()) == src)
                and (cond is None or cond(m))]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


class Repeater:
    """Sends ``make()`` from ``peer`` at ``hz`` on a thread until stopped (a flood, or an autopilot's stream)."""

    def __init__(self, peer: Peer, make, hz: float) -> None:
        self.peer, self.make, self.period = peer, make, 1.0 / hz
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            for msg in self.make():
                self.peer.send(msg)
                self.sent += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2)


def sub_heartbeat() -> mav2.MAVLink_message:
    return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)


def gcs_heartbeat() -> mav2.MAVLink_message:
    return mav2.MAVLink_heartbeat_message(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)


def boot_ms(start: float) -> int:
    return int((time.monotonic() - start) * 1000) + 1000
