"""A tiny MAVLink-agnostic UDP hub: what BlueOS' router does on a vehicle, for the demo, tests and benches.

Every datagram from one peer goes to every other peer. Peers are learnt from the first datagram they send
(``udpout:`` clients: the simulated autopilot, the companion) or given up front (a surface tool listening with
``udpin:``). Datagrams are forwarded whole, so MAVLink framing, CRCs and signing pass through untouched.
"""

from __future__ import annotations

import socket
import threading


class UdpHub:
    def __init__(self, host: str = "127.0.0.1", port: int = 0, outputs: list[tuple[str, int]] | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.settimeout(0.2)
        self.host, self.port = self.sock.getsockname()[:2]
        self.peers: list[tuple[str, int]] = list(outputs or [])
        self.forwarded = 0
        self.bytes = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def url(self) -> str:
        """The connection string a client uses to join (``udpout:``)."""
        return f"udpout:{self.host}:{self.port}"

    def start(self) -> UdpHub:
        self._thread = threading.Thread(target=self._run, name="udp-hub", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, sender = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            with self._lock:
                if sender not in self.peers:
                    self.peers.append(sender)
                targets = [p for p in self.peers if p != sender]
            for peer in targets:
                try:
                    self.sock.sendto(data, peer)
                    self.forwarded += 1
                    self.bytes += len(data)
                except OSError:
                    continue  # a peer that went away; it comes back by sending again

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        self.sock.close()
