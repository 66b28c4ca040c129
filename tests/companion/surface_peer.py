"""A companion stand-in for the surface tool's tests, built from the real companion-side pieces.

It packs real MAVLink 2 messages (vehicle/camera/captures.py, vehicle/protocol/image_push.py, vehicle/camera/status.py) onto a real UDP
socket on 127.0.0.1 and answers FTP with the real ``vehicle.camera.ftp_server.FtpServer``. Only the scheduling is the
test's own (no byte budget), so a test can drop exactly the packets it wants lost.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.vision.events import SummaryFrame
from vehicle.autopilot.pose import Pose
from vehicle.camera.captures import CaptureLog, added_text, thumbnail_path, trimmed_text
from vehicle.camera.component import CameraComponent
from vehicle.camera.ftp_server import FtpServer, VirtualTree, crc32_ardupilot
from vehicle.camera.status import push_marker
from vehicle.camera.thumbnails import make_thumbnail
from vehicle.protocol.image_push import push_messages


def summary_frame(index: int, *, depth: float = 12.5, yaw_deg: float = 90.0, score: float = 0.8) -> SummaryFrame:
    """A real-looking frame: a colour gradient with the index drawn on it, tagged with depth and heading."""
    h, w = 270, 480
    x = np.linspace(0, 255, w, dtype=np.float32)
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = (x[None, :] * 0.6 + index * 37) % 256
    img[..., 1] = np.linspace(60, 200, h, dtype=np.float32)[:, None]
    img[..., 2] = 40
    cv2.putText(img, f"#{index}", (150, 180), cv2.FONT_HERSHEY_SIMPLEX, 4, (255, 255, 255), 8)
    yaw = np.radians(yaw_deg)
    pose = Pose(time=time.time(), age_s=0.05, stale=False, depth_m=depth, depth_source="global_position_int",
                roll=0.0, pitch=0.0, yaw=float(yaw), heading_deg=yaw_deg % 360)
    return SummaryFrame(image_index=index, frame_index=index * 10, time_s=index * 1.0, capture_time=time.time(),
                        score=score, image=img, feature=np.zeros(8, np.float32), pose=pose)


class CompanionPeer:
    """Sends as system 1 component 100 to ``port``; answers FTP requests on a thread until ``close``."""

    def __init__(self, port: int, *, system: int = 1, component: int = 100, markers: bool = False,
                 index_crc: bool = False) -> None:
        """``markers``: send MRL_PUSH before each push, and ``index_crc``: put each thumbnail's size and CRC32 in
        index.json, as the real companion does; without them, an older or foreign companion."""
        self.markers = markers
        self.index_crc = index_crc
        self.addr = ("127.0.0.1", port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.mav = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        self.tree = VirtualTree()
        self.ftp = FtpServer(self.tree)
        self.captures = CaptureLog()
        self.camera = CameraComponent(self.captures, system_id=lambda: system, component_id=component)
        self.frames: dict[int, SummaryFrame] = {}
        self.thumbs: dict[int, bytes] = {}
        self.held: list[int] = []
        self.drop_ftp_reply: Callable[[int], bool] = lambda n: False
        """Called with a running reply number: True drops that FTP reply (a lossy link)."""
        self.ftp_replies = 0
        self.ftp_requests = 0
        self.received: list = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        self.tree.put("/summary/index.json", self._index)

    def send(self, msg) -> None:
        with self._lock:
            self.sock.sendto(msg.pack(self.mav), self.addr)
            self.mav.seq = (self.mav.seq + 1) % 256

    def heartbeat(self) -> None:
        self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def add(self, frame: SummaryFrame, *, push: bool = True, drop_chunks: set[int] = frozenset(),
            announce: bool = True) -> bytes:
        """Announce a frame (``announce=False``: the announcement is lost), say so in a status line, serve its
        thumbnail by FTP and (unless told) push it."""
        thumb = make_thumbnail(frame.image)
        self.frames[frame.image_index] = frame
        self.thumbs[frame.image_index] = thumb.data
        self.held.append(frame.image_index)
        self.tree.put(thumbnail_path(frame.image_index), thumb.data)
        captured = self.captures.record(frame)
        if announce:
            self.send(captured)
        self.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, added_text(frame, len(self.held)).encode()))
        if push:
            self.push(thumb.data, thumb.width, thumb.height, drop_chunks=drop_chunks, index=frame.image_index)
        return thumb.data

    def push(self, data: bytes, width: int, height: int, *, drop_chunks: set[int] = frozenset(),
             index: int | None = None) -> None:
        if self.markers and index is not None:
            self.send(push_marker(index, 0))
        for i, msg in enumerate(push_messages(data, width, height, 80)):
            if i - 1 in drop_chunks:
                continue
            self.send(msg)
            time.sleep(0.001)  # the loopback socket buffer is small; a real link is far slower still

    def trim(self, index: int) -> None:
        self.held.remove(index)
        self.tree.remove(thumbnail_path(index))
        self.send(mav.MAVLink_statustext_message(
            mav.MAV_SEVERITY_INFO, trimmed_text(self.frames[index], len(self.held)).encode()))

    def values(self, **values: float) -> None:
        for name, value in values.items():
            self.send(mav.MAVLink_named_value_float_message(0, name.encode(), value))

    def _index(self) -> bytes:
        frames = []
        for i in self.held:
            f = self.frames[i]
            entry = {"image_index": i, "time_utc": f.capture_time, "score": f.score, "depth_m": f.pose.depth_m,
                     "heading_deg": f.pose.heading_deg, "thumbnail": thumbnail_path(i)}
            if self.index_crc:
                entry.update(thumbnail_bytes=len(self.thumbs[i]), thumbnail_crc32=crc32_ardupilot(self.thumbs[i]))
            frames.append(entry)
        return json.dumps({"frames": frames}).encode()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, _who = self.sock.recvfrom(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            for msg in self.parser.parse_buffer(data) or []:
                self.received.append(msg)
                if msg.get_type() == "COMMAND_LONG":
                    for answer in self.camera.handle(msg):  # the real camera component answers requests
                        self.send(answer)
                    continue
                if msg.get_type() != "FILE_TRANSFER_PROTOCOL":
                    continue
                self.ftp_requests += 1
                requester = (msg.get_srcSystem(), msg.get_srcComponent())
                replies = [(requester, r) for r in self.ftp.handle(bytes(msg.payload), requester)]
                while (burst := self.ftp.next_burst()) is not None:  # no budget here: the whole burst at once
                    replies.append(burst)
                for (system, component), reply in replies:
                    self.ftp_replies += 1
                    if self.drop_ftp_reply(self.ftp_replies):
                        continue
                    self.send(mav.MAVLink_file_transfer_protocol_message(0, system, component, list(reply)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


class LossyRelay:
    """A UDP relay between a companion (sending to ``port``) and the surface tool at ``target``, dropping every
    datagram for which ``drop(n)`` is True (n counts datagrams in both directions): a lossy radio or tether."""

    def __init__(self, target_port: int, drop: Callable[[int], bool]) -> None:
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the companion's side
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the surface tool's side
        self.back.bind(("127.0.0.1", 0))
        for s in (self.front, self.back):
            s.settimeout(0.05)
        self.port = self.front.getsockname()[1]
        self.target = ("127.0.0.1", target_port)
        self.drop = drop
        self.count = 0
        self.dropped = 0
        self._companion: tuple[str, int] | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._pump, args=(self.front, True), daemon=True),
                         threading.Thread(target=self._pump, args=(self.back, False), daemon=True)]
        for t in self._threads:
            t.start()

    def _pump(self, sock: socket.socket, upward: bool) -> None:
        while not self._stop.is_set():
            try:
                data, who = sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                self.count += 1
                lose = self.drop(self.count)
                self.dropped += lose
            if upward:
                self._companion = who
            if lose:
                continue
            if upward:
                self.back.sendto(data, self.target)
            elif self._companion is not None:
                self.front.sendto(data, self._companion)

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2)
        self.front.close()
        self.back.close()
