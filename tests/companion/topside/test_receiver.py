"""The image-push receiver and the message parsers, against what the real companion-side code sends."""

from __future__ import annotations

import dataclasses
import socket
import time

import cv2
import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import SurfaceConfig
from companion.topside.gallery import Topic
from companion.topside.messages import (
    capture_from_message,
    heading_from_q,
    index_topics,
    mftp_path,
    parse_index,
    parse_statustext,
)
from companion.vision.events import SummaryEvent
from tests.companion.surface_peer import CompanionPeer, summary_frame
from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link
from vehicle.camera.captures import added_text, captured_message, trimmed_text
from vehicle.camera.downlink import Downlink
from vehicle.camera.thumbnails import make_thumbnail
from vehicle.protocol.image_push import Abandoned, ImageReceiver, LostHandshake, PushedImage
from vehicle.protocol.queries import QueryTopic


def _receive(sock: socket.socket, receiver: ImageReceiver, want: int, timeout: float = 5.0) -> list:
    """Read the socket, feeding the receiver, until ``want`` results (finished or abandoned) came."""
    parser = mav.MAVLink(None)
    out: list = []
    end = time.monotonic() + timeout
    while len(out) < want and time.monotonic() < end:
        try:
            data = sock.recv(4096)
        except TimeoutError:
            continue
        for msg in parser.parse_buffer(data) or []:
            result = receiver.handle(msg)
            if result is not None:
                out.append(result)
    return out


def _pair() -> tuple[socket.socket, CompanionPeer]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    return sock, CompanionPeer(sock.getsockname()[1])


def test_pushed_thumbnails_arrive_intact_over_udp():
    sock, peer = _pair()
    try:
        thumbs = [make_thumbnail(summary_frame(i).image) for i in range(3)]
        for t in thumbs:
            peer.push(t.data, t.width, t.height)
        got = _receive(sock, ImageReceiver(), 3)
    finally:
        peer.close()
        sock.close()
    assert [type(g) for g in got] == [PushedImage] * 3
    assert [g.data for g in got] == [t.data for t in thumbs]
    assert (got[0].width, got[0].height, got[0].kind, got[0].source) == (thumbs[0].width, thumbs[0].height,
                                                                        "jpeg", (1, 100))
    image = cv2.imdecode(np.frombuffer(got[2].data, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (thumbs[2].height, thumbs[2].width, 3)


def test_a_lost_chunk_stalls_the_image_until_the_next_handshake():
    sock, peer = _pair()
    try:
        first, second = (make_thumbnail(summary_frame(i).image) for i in (4, 5))
        assert len(first.data) > 2 * 253  # several chunks, so one can go missing
        peer.push(first.data, first.width, first.height, drop_chunks={1})
        peer.push(second.data, second.width, second.height)
        receiver = ImageReceiver()
        got = _receive(sock, receiver, 2)
    finally:
        peer.close()
        sock.close()
    assert isinstance(got[0], Abandoned) and got[0].handshake_no == 1
    assert got[0].received_packets == got[0].packets - 1
    assert isinstance(got[1], PushedImage) and got[1].data == second.data and got[1].handshake_no == 2
    assert (receiver.completed, receiver.abandoned) == (1, 1)


def test_capture_message_becomes_depth_heading_and_ftp_path():
    frame = summary_frame(7, depth=23.25, yaw_deg=250.0)
    msg = captured_message(frame, 1234)
    decoded = mav.MAVLink(None).decode(bytearray(msg.pack(mav.MAVLink(None, srcSystem=1, srcComponent=100))))
    cap = capture_from_message(decoded)
    assert cap.image_index == 7
    assert cap.depth_m == 23.25
    assert abs(cap.heading_deg - 250.0) < 0.2
    assert abs(cap.time_utc - frame.capture_time) < 1e-3
    assert mftp_path(cap.file_url) == "/summary/7.jpg"
    assert cap.lat is None and cap.lon is None


def test_heading_of_unknown_attitude_is_none():
    assert heading_from_q([float("nan"), 0, 0, 0]) is None
    assert heading_from_q([0, 0, 0, 0]) is None
    assert heading_from_q([1, 0, 0, 0]) == 0.0
    assert parse_index(b'[{"index": 1, "heading_deg": 359.99999}, {"index": 2, "heading_deg": -90}]')[0].heading_deg == 0.0
    assert parse_index(b'[{"index": 2, "heading_deg": -90}]')[0].heading_deg == 270.0


def test_status_lines_of_the_companion_are_understood():
    frame = summary_frame(12, score=0.83)
    added = parse_statustext(added_text(frame, 4))
    assert added.added == [12] and added.scores == {12: 0.83} and added.removed == []
    trimmed = parse_statustext(trimmed_text(frame, 3))
    assert trimmed.removed == [12] and trimmed.added == []
    assert parse_statustext("Frame #9 trimmed out").removed == [9]
    assert parse_statustext("Summary changed").summary_changed
    assert parse_statustext("Encoder: imagenet (no CLIP weights)").removed == []


def test_index_json_in_the_shapes_we_accept():
    caps = parse_index(b'{"frames": [{"image_index": 3, "score": 0.5, "pose": {"depth_m": 4.0, "heading_deg": 10},'
                       b' "time_utc": 1700000000000000, "thumbnail": "/summary/3.jpg"}]}')
    assert len(caps) == 1
    c = caps[0]
    assert (c.image_index, c.score, c.depth_m, c.heading_deg) == (3, 0.5, 4.0, 10.0)
    assert c.time_utc == 1700000000.0 and c.file_url == "mftp://summary/3.jpg"
    assert [c.image_index for c in parse_index(b'[{"index": 1}, {"index": 2}]')] == [1, 2]


def test_packets_without_their_handshake_are_reported_once():
    sock, peer = _pair()
    try:
        thumb = make_thumbnail(summary_frame(9).image)
        peer.push(thumb.data, thumb.width, thumb.height, drop_chunks={-1})  # -1: the handshake itself
        receiver = ImageReceiver()
        got = _receive(sock, receiver, 1)
        more = _receive(sock, receiver, 1, timeout=0.5)  # the image's other packets: nothing more to say
    finally:
        peer.close()
        sock.close()
    assert [type(g) for g in got] == [LostHandshake]
    assert got[0].source == (1, 100) and more == []


def test_a_lost_packet_and_a_lost_handshake_never_make_a_mixed_image():
    sock, peer = _pair()
    try:
        first, second = (make_thumbnail(summary_frame(i).image) for i in (10, 11))
        assert len(first.data) // 253 == len(second.data) // 253  # same packet count: mixing them would "work"
        peer.push(first.data, first.width, first.height, drop_chunks={3})
        peer.push(second.data, second.width, second.height, drop_chunks={-1})
        receiver = ImageReceiver()
        got = _receive(sock, receiver, 1)
        more = _receive(sock, receiver, 1, timeout=0.5)
    finally:
        peer.close()
        sock.close()
    assert len(got) == 1 and isinstance(got[0], Abandoned) and got[0].next_headless
    assert got[0].chunks[0] == first.data[:253] and 3 * 253 not in got[0].chunks
    assert more == []  # the second image's packets are not taken for the first one's missing packet


def test_the_topic_of_a_new_frame_is_read_from_its_status_line():
    frame = dataclasses.replace(summary_frame(12, score=0.83), topic="coral_reef")
    named = parse_statustext(added_text(frame, 4, topic=True))
    assert named.added == [12] and named.scores == {12: 0.83} and named.topics == {12: "coral_reef"}
    assert parse_statustext(added_text(frame, 4)).topics == {}  # one topic followed: the line names none
    long = dataclasses.replace(frame, image_index=123456, topic="a" * 24)
    cut = added_text(long, 4, topic=True)
    assert parse_statustext(cut).topics in ({123456: "a" * 24}, {})  # never a name cut short
    assert parse_statustext("Summary +#7 fis").topics == {}
    assert parse_statustext("Topics set: fish, coral").summary_changed  # index.json lists the new topics


def test_the_topics_and_each_frames_topic_come_from_the_companions_index():
    link = companion_link(free_udp_port())
    topics = [QueryTopic("fish", "underwater image with fish", ("underwater image without fish",)),
              QueryTopic("coral", "a coral reef", ("sand", "rocks"))]
    surface = Downlink(link, SurfaceConfig(push=False), queries=topics)
    try:
        surface.start()
        surface.publish(SummaryEvent("added", dataclasses.replace(summary_frame(3), topic="fish"), summary=[3]))
        surface.publish(SummaryEvent("added", dataclasses.replace(summary_frame(4), topic="coral"), summary=[3, 4]))
        index = surface.index_json()
    finally:
        surface.stop()
        link.stop()
    assert index_topics(index) == [Topic("fish", "underwater image with fish", ("underwater image without fish",)),
                                   Topic("coral", "a coral reef", ("sand", "rocks"))]
    assert {c.image_index: c.topic for c in parse_index(index)} == {3: "fish", 4: "coral"}
    assert index_topics(b'{"summary": [{"image_index": 1}]}') is None  # an older companion names no topics
    assert parse_index(b'{"summary": [{"image_index": 1}]}')[0].topic is None
