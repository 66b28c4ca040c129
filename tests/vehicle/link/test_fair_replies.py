"""Issue 46 item 1, the accounting: answers to unsigned requesters share one slice of the link by bytes, answers
never take more than their share of the bytes from waiting captures and thumbnails, and the replies of a
requester that went quiet expire. The link is the real ``MavLink`` writing datagrams (``test_budget``); only the
clock is simulated, so a minute of a 200-id flood is accounted exactly in about a second."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.vehicle.link.test_budget import _ftp_chunk, _setup
from vehicle.camera.status import status_text
from vehicle.link.budget import LinkBudget, Priority
from vehicle.link.fair_replies import QUIET_S, FairReplies, UnsignedSlice, wire_estimate

RATE = 2000


def _param_value(i: int) -> mav.MAVLink_message:
    return mav.MAVLink_param_value_message(f"MERL_P{i % 10}".encode(), float(i), 9, 10, i % 10)


def _chunk(seq: int) -> mav.MAVLink_message:
    return mav.MAVLink_encapsulated_data_message(seq, [seq % 250 + 1] * 253)


def _bytes(link, kind: str, start: float = 0.0, end: float = float("inf")) -> int:
    return sum(n for when, n, k in link.log if k == kind and start <= when < end)


def test_two_hundred_unsigned_ids_share_one_slice_and_captures_and_thumbnails_keep_theirs():
    sink, clock, link = _setup()
    try:
        budget = LinkBudget(link, RATE, clock=clock)
        slice_ = UnsignedSlice(lambda: budget.rate, clock=clock)
        replies = FairReplies(slice_, clock=clock)
        budget.add_source(Priority.CONTROL, replies.next)
        start = clock.now
        flood_end, end = start + 60.0, start + 75.0
        sent_thumbs, asked, step = 0, 0, 0
        while clock.now < end:
            if clock.now < flood_end:  # 1,500 requests a second from 200 made-up ids, one answer each
                for _ in range(15):
                    replies.submit((1 + asked % 200, 190, False), [_param_value(asked)])
                    asked += 1
            if step % 300 == 0 and clock.now < flood_end:  # every 3 s a capture, its line and a 10-chunk thumbnail push
                budget.submit(status_text(f"Summary +#{step // 300}"), Priority.STATUS)
                for _ in range(10):
                    budget.submit(_chunk(sent_thumbs), Priority.THUMBNAIL)
                    sent_thumbs += 1
            if step % 100 == 0:  # the 1 Hz status values
                for name in ("fps", "score", "summary", "depth"):
                    budget.submit(status_text(name), Priority.STATUS, tag=name, replace=True)
            budget.pump()
            clock.now += 0.01
            step += 1
        answers = _bytes(link, "PARAM_VALUE", start, flood_end)
        print(f"\n60 s of 1,500 unsigned requests/s from 200 ids at {RATE} B/s: answers {answers / 60:.0f} B/s, "
              f"thumbnails {_bytes(link, 'ENCAPSULATED_DATA') / 60:.0f} B/s, {replies.stats()}")
        # one slice for all 200 (25%, and its half-second burst), used while the flood asks
        assert 0.5 * 0.25 * RATE * 60 <= answers <= 0.25 * RATE * 60 + 0.125 * RATE + 300
        kinds = [k for _, _, k in link.log]
        assert kinds.count("ENCAPSULATED_DATA") == sent_thumbs  # every thumbnail chunk went...
        last_chunk = max(when for when, _, k in link.log if k == "ENCAPSULATED_DATA")
        assert last_chunk < flood_end + 3.0  # ...in time, not seconds late behind a queue
        assert kinds.count("STATUSTEXT") >= 20 + 60 * 4 * 0.9  # captures' lines, status values
        # the flood stopped: its queued answers expire once the ids are quiet, nothing is sent for them after
        assert _bytes(link, "PARAM_VALUE", flood_end + QUIET_S + 0.5) == 0
        assert replies.stats()["expired"] > 0 and replies.pending() == 0 and replies.stats()["requesters"] == 0
    finally:
        link.stop()
        sink.close()


def test_answers_get_half_the_bytes_while_small_status_lines_and_thumbnails_wait():
    """A signed requester's answers without end, status lines of 60 bytes and a thumbnail push: answers take half
    the bytes; a small status line no longer buys 560 bytes of answers, so the push behind it goes."""
    sink, clock, link = _setup()
    try:
        budget = LinkBudget(link, RATE, clock=clock)
        replies = FairReplies(UnsignedSlice(lambda: budget.rate, clock=clock), clock=clock)
        budget.add_source(Priority.CONTROL, replies.next)
        start = clock.now
        seq = 0
        for step in range(3000):  # 30 s
            if replies.pending() < 10:
                replies.submit((255, 190, True), [_ftp_chunk(seq + i) for i in range(10)])
                seq += 10
            if step % 25 == 0:
                budget.submit(status_text(f"status {step}"), Priority.STATUS)
            if budget.pending(Priority.THUMBNAIL) < 5:
                budget.submit(_chunk(step), Priority.THUMBNAIL)
            budget.pump()
            clock.now += 0.01
        answers = _bytes(link, "FILE_TRANSFER_PROTOCOL", start + 1)
        status = _bytes(link, "STATUSTEXT", start + 1)
        thumbs = _bytes(link, "ENCAPSULATED_DATA", start + 1)
        total = answers + status + thumbs
        print(f"\nanswers {answers / total:.0%}, status {status / total:.0%}, thumbnails {thumbs / total:.0%}")
        assert 0.45 <= answers / total <= 0.55
        assert thumbs / total >= 0.3
        assert budget.pending(Priority.STATUS) <= 1  # every status line went at once
    finally:
        link.stop()
        sink.close()


def test_a_quiet_requesters_replies_expire_and_one_that_keeps_asking_is_served():
    clock_now = [100.0]
    slice_ = UnsignedSlice(lambda: 1000.0, clock=lambda: clock_now[0])
    replies = FairReplies(slice_, clock=lambda: clock_now[0])
    gone, asking = (7, 190, False), (8, 190, False)
    assert replies.submit(gone, [_param_value(i) for i in range(64)]) == 64
    assert replies.submit(gone, [_param_value(64)]) == 0  # its queue is full: dropped, counted
    served = []
    for step in range(80):  # 8 s: the slice sends 250 B/s, the asking one asks once a second
        clock_now[0] += 0.1
        if step % 10 == 0:
            replies.submit(asking, [_param_value(1000 + step)])
        while (msg := replies.next()) is not None:
            served.append(msg.param_value)
    from_gone = [v for v in served if v < 1000]
    from_asking = [v for v in served if v >= 1000]
    assert 0 < len(from_gone) < 64  # some went before it fell quiet, the rest expired
    assert replies.stats()["expired"] == 64 - len(from_gone)
    assert from_asking == [1000.0 + 10 * i for i in range(8)]  # every answer to the one still asking
    assert replies.stats()["requesters"] == 1 and replies.stats()["dropped"] == 1


def test_turns_are_counted_in_bytes_between_requesters():
    """Two signed requesters, one of full FTP frames, one of small parameter values: each gets half the bytes
    (a turn per message had given the large one five times the other's)."""
    now = [0.0]
    replies = FairReplies(UnsignedSlice(lambda: 1000.0, clock=lambda: now[0]), clock=lambda: now[0])
    big, small = (255, 190, True), (255, 191, True)
    got = {big: 0, small: 0}
    for i in range(2000):
        for who, make in ((big, _ftp_chunk), (small, _param_value)):
            if replies.pending() < 100:
                replies.submit(who, [make(i)])
        msg = replies.next()
        size = wire_estimate(msg)  # its size on a signed link, as the turns count it
        got[big if msg.get_type() == "FILE_TRANSFER_PROTOCOL" else small] += size
    assert 0.95 <= got[big] / got[small] <= 1.05, got
