"""Budget accounting: wire bytes within 5% of the budget over every 10 s window, priorities, dropped thumbnails.

The link is the team's real ``MavLink`` writing real datagrams to a UDP socket; only the clock is simulated, so a
minute of traffic is accounted exactly in well under a second and no assertion depends on the machine's speed.
"""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import MavlinkConfig
from vehicle.camera.status import status_text
from vehicle.link.budget import LinkBudget, Priority
from vehicle.link.connection import MavLink


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class RecordingLink(MavLink):
    """The real link, noting (simulated time, wire bytes, message type) for every datagram it writes."""

    def __init__(self, port: int, clock: Clock) -> None:
        super().__init__(f"udpout:127.0.0.1:{port}", MavlinkConfig(system_id=1, component_id=100), clock=clock,
                         heartbeat=False)
        self.sim_clock = clock
        self.log: list[tuple[float, int, str]] = []

    def send(self, msg):
        n = super().send(msg)
        self.log.append((self.sim_clock(), n, msg.get_type()))
        return n


def _setup():
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    clock = Clock()
    link = RecordingLink(sink.getsockname()[1], clock)
    link.start()
    assert link.wait_open(5)
    return sink, clock, link


def _ftp_chunk(seq: int) -> mav.MAVLink_message:
    return mav.MAVLink_file_transfer_protocol_message(0, 255, 190, [(seq + i) % 251 + 1 for i in range(251)])


def test_every_ten_second_window_stays_within_five_percent():
    sink, clock, link = _setup()
    try:
        rate = 2000
        budget = LinkBudget(link, rate, clock=clock)
        seq = iter(range(10**9))
        idle = (clock.now + 20.0, clock.now + 26.0)  # FTP pauses, then bursts again: the bucket must not hoard
        budget.add_source(Priority.BULK,
                          lambda: None if idle[0] <= clock.now < idle[1] else _ftp_chunk(next(seq)))
        for idx in range(40):
            budget.submit(status_text(f"line {idx}"), Priority.STATUS)
        next_beat = clock.now
        end = clock.now + 60.0
        while clock.now < end:
            if clock.now >= next_beat:  # the link's own heartbeat bypasses the budget; it must still count
                link.send(link.heartbeat_message())
                next_beat += 1.0
            budget.pump()
            clock.now += 0.005
        assert link.tx_bytes > 0 and sink.recv(4096)  # real datagrams went out
        start = link.log[0][0]
        worst_hi, worst_lo = 0.0, float("inf")
        t = start + 1.0
        while t + 10.0 <= end:
            sent = sum(n for when, n, _ in link.log if t <= when < t + 10.0)
            worst_hi = max(worst_hi, sent)
            if t + 10.0 <= idle[0] or t >= idle[1]:
                worst_lo = min(worst_lo, sent)
            t += 0.25
        assert worst_hi <= 1.05 * rate * 10, worst_hi
        assert worst_lo >= 0.95 * rate * 10, worst_lo  # a saturated link uses its budget
        kinds = [k for _, _, k in link.log]
        assert kinds.count("HEARTBEAT") >= 59
        first_ftp = kinds.index("FILE_TRANSFER_PROTOCOL")
        assert kinds[:first_ftp].count("STATUSTEXT") == 40  # status went before bulk
    finally:
        link.stop()
        sink.close()


def test_priorities_and_dropping_by_tag():
    sink, clock, link = _setup()
    try:
        budget = LinkBudget(link, 1000, clock=clock)
        for seq in range(6):
            budget.submit(mav.MAVLink_encapsulated_data_message(seq, [seq + 1] * 253), Priority.THUMBNAIL,
                          tag=("thumb", 1))
        budget.submit(mav.MAVLink_encapsulated_data_message(0, [9] * 253), Priority.THUMBNAIL, tag=("thumb", 2))
        budget.submit(status_text("hello"), Priority.STATUS)
        budget.submit(mav.MAVLink_command_ack_message(512, 0, 0, 0, 255, 190), Priority.CONTROL)
        assert budget.drop(("thumb", 1)) == 6
        for _ in range(400):
            budget.pump()
            clock.now += 0.01
        kinds = [k for _, _, k in link.log]
        assert kinds == ["COMMAND_ACK", "STATUSTEXT", "ENCAPSULATED_DATA"]
        budget.submit(status_text("a"), Priority.STATUS, tag="s", replace=True)
        budget.submit(status_text("b"), Priority.STATUS, tag="s", replace=True)
        assert budget.pending(Priority.STATUS) == 1  # a newer value replaces a queued one
        ack = mav.MAVLink_command_ack_message(512, 0, 0, 0, 255, 190)
        assert budget.submit(ack, Priority.CONTROL, tag="reply-7", unique=True)
        assert not budget.submit(ack, Priority.CONTROL, tag="reply-7", unique=True)  # retransmission: one copy
        assert budget.pending(Priority.CONTROL) == 1
        assert budget.in_use_bps(10) > 0
    finally:
        link.stop()
        sink.close()
