"""Live sources: the generated dive, the retrying wrapper, V4L2 (mocked: no camera here) and RTP/UDP set-up."""

from __future__ import annotations

import os
import shutil
import subprocess
import threading

import cv2
import numpy as np
import pytest

from companion.config import SourceConfig
from companion.errors import MerlionError, UsageError
from companion.sources import stream
from companion.sources.base import FrameSource
from companion.sources.capture import SourceLost
from companion.sources.retrying import RetryingSource
from companion.sources.stream import StreamSource, parse_udp, rtp_h264_sdp
from companion.sources.synthetic import (
    FISH_SEGMENTS,
    SEGMENTS,
    SyntheticSource,
    parse_synthetic_uri,
    segment_at,
)
from companion.sources.v4l2 import V4L2Source, is_v4l2
from tests.conftest import free_udp_port, shared_file


def take(source, n: int) -> list:
    out = []
    for frame in source:
        out.append(frame)
        if len(out) >= n:
            break
    return out


def test_synthetic_dive_is_deterministic_and_walks_through_its_segments() -> None:
    uri = "synthetic://dive?seconds=1&width=160&height=96"
    a = take(SyntheticSource(uri, fps=2, realtime=False), 12)
    b = take(SyntheticSource(uri, fps=2, realtime=False), 12)
    assert [f.index for f in a] == list(range(12))
    assert [f.time_s for f in a] == pytest.approx([i / 2 for i in range(12)])
    for fa, fb in zip(a, b, strict=True):
        assert fa.image.shape == (96, 160, 3) and fa.image.dtype == np.uint8
        np.testing.assert_array_equal(fa.image, fb.image)
    assert [segment_at(f.time_s, 1.0) for f in a[::2]] == [*SEGMENTS, SEGMENTS[0]]
    assert FISH_SEGMENTS <= set(SEGMENTS)
    # scenes differ from one another (not one picture repeated)
    assert np.abs(a[0].image.astype(int) - a[4].image.astype(int)).mean() > 5


def test_synthetic_ends_after_the_segments_asked_for() -> None:
    frames = list(SyntheticSource("synthetic://dive?seconds=1&segments=2&width=64&height=48", fps=4, realtime=False))
    assert len(frames) == 8


@pytest.mark.parametrize("uri", ["synthetic://reef", "synthetic://dive?colour=red", "synthetic://dive?seconds=-1"])
def test_bad_synthetic_uri_is_a_usage_error(uri: str) -> None:
    with pytest.raises(UsageError, match="source"):
        parse_synthetic_uri(uri)


class Flaky(FrameSource):
    """A real synthetic camera that dies after a few frames, as an unplugged camera does."""

    def __init__(self, frames: int) -> None:
        self.inner = SyntheticSource("synthetic://dive?width=64&height=48", fps=50, realtime=False)
        self.frames = frames
        self.closed = False

    def __iter__(self):
        for i, frame in enumerate(self.inner):
            if i >= self.frames:
                raise SourceLost("camera unplugged")
            yield frame

    def close(self) -> None:
        self.closed = True


def test_a_source_that_disappears_is_retried_with_back_off_and_returns() -> None:
    attempts = []
    states = []

    def opener() -> FrameSource:
        attempts.append(len(attempts))
        if len(attempts) in (2, 3):
            raise OSError("no such device /dev/video0")
        return Flaky(3)

    source = RetryingSource(opener, name="cam", live=True, initial_s=0.01, max_s=0.04,
                            on_state=lambda s, d: states.append(s))
    frames = take(source, 9)
    source.close()
    assert len(frames) == 9
    assert [f.index for f in frames] == sorted({f.index for f in frames}), "indices keep growing across reopens"
    assert source.failures >= 4 and len(attempts) >= 4
    assert states[:3] == ["running", "retrying", "running"]
    assert "camera unplugged" in source.last_error or "no such device" in source.last_error


def test_a_file_like_source_ends_once_or_loops() -> None:
    def opener() -> FrameSource:
        return SyntheticSource("synthetic://dive?seconds=1&segments=1&width=64&height=48", fps=5, realtime=False)

    once = RetryingSource(opener, name="clip", live=False)
    assert len(list(once)) == 5 and once.state == "ended"
    looping = RetryingSource(opener, name="clip", live=False, loop=True)
    frames = take(looping, 12)
    assert [f.index for f in frames] == list(range(12)) and looping.ended == 2


def test_close_interrupts_a_long_back_off() -> None:
    source = RetryingSource(lambda: (_ for _ in ()).throw(OSError("gone")), name="cam", live=True,
                            initial_s=60, max_s=60)
    done = threading.Event()

    def drain() -> None:
        list(source)
        done.set()

    threading.Thread(target=drain, daemon=True).start()
    threading.Timer(0.2, source.close).start()
    assert done.wait(10), "close() must end the back-off wait"
    assert source.state == "closed"


class FakeV4L2Capture:
    """Stands in for cv2.VideoCapture on a V4L2 device (no camera can exist on a build machine)."""

    instances: list[FakeV4L2Capture] = []

    def __init__(self, path: str, api: int) -> None:
        self.path, self.api, self.props = path, api, {}
        self.reads = 0
        FakeV4L2Capture.instances.append(self)

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return True

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        return float(self.props.get(prop, 0))

    def read(self):
        self.reads += 1
        if self.reads > 6:
            return False, None
        return True, np.full((48, 64, 3), self.reads, np.uint8)

    def release(self) -> None:
        pass


def test_v4l2_asks_for_the_configured_mode_and_reports_loss() -> None:
    FakeV4L2Capture.instances.clear()
    cfg = SourceConfig(uri="/dev/video2", width=1280, height=720, fourcc="MJPG", fps=240)
    source = V4L2Source(cfg, video_capture=FakeV4L2Capture)
    source.max_failed_reads = 2
    frames = []
    with pytest.raises(SourceLost):
        for frame in source:
            frames.append(frame)
    cap = FakeV4L2Capture.instances[0]
    assert cap.path == "/dev/video2" and cap.api == cv2.CAP_V4L2
    assert cap.props[cv2.CAP_PROP_FRAME_WIDTH] == 1280 and cap.props[cv2.CAP_PROP_FRAME_HEIGHT] == 720
    assert cap.props[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter_fourcc(*"MJPG")
    assert len(frames) >= 1 and frames[0].image.shape == (48, 64, 3)
    assert is_v4l2("/dev/video0") and not is_v4l2("clip.mp4")


def test_udp_rtp_source_description() -> None:
    assert parse_udp("udp://@:5600") == ("0.0.0.0", 5600)
    assert parse_udp("udp://127.0.0.1:5601") == ("127.0.0.1", 5601)
    with pytest.raises(UsageError):
        parse_udp("udp://@:notaport")
    sdp = rtp_h264_sdp(5600)
    assert "m=video 5600 RTP/AVP 96" in sdp and "H264/90000" in sdp


def stream_rtp(path, port: int) -> subprocess.Popen:
    """ffmpeg sending RTP/H.264 to a UDP port, as a BlueROV2 camera pipeline sends to port 5600."""
    return subprocess.Popen(
        ["ffmpeg", "-loglevel", "error", "-re", "-stream_loop", "-1", "-i", str(path), "-an", "-c:v", "libx264",
         "-preset", "ultrafast", "-tune", "zerolatency", "-g", "10", "-f", "rtp", "-payload_type", "96",
         f"rtp://127.0.0.1:{port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed (apt-get install ffmpeg)")
def test_rtp_h264_stream_is_received_lost_and_reopened(monkeypatch) -> None:
    clip = shared_file("aquarium_fish/fish.mp4")
    monkeypatch.setattr(stream, "READ_TIMEOUT_MS", 1000)  # the loss is noticed after two silent reads: 2 s, not 5
    port = free_udp_port()
    states: list[str] = []
    frames: list = []
    seen = threading.Condition()

    def on_state(state: str, detail: str) -> None:
        with seen:
            states.append(state)
            seen.notify_all()

    cfg = SourceConfig(uri=f"udp://127.0.0.1:{port}", fps=5)
    source = RetryingSource(lambda: StreamSource(cfg), name=cfg.uri, live=True, initial_s=0.2, max_s=0.5,
                            on_state=on_state)

    def drain() -> None:
        for frame in source:
            with seen:
                frames.append(frame)
                seen.notify_all()

    sender = stream_rtp(clip, port)
    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        with seen:
            assert seen.wait_for(lambda: len(frames) >= 3, 60), "no frames from the RTP stream"
        assert frames[0].image.shape == (360, 640, 3)
        sender.terminate()
        sender.wait(10)
        with seen:
            assert seen.wait_for(lambda: "retrying" in states, 60), "the lost stream was not noticed"
            before = len(frames)
        sender = stream_rtp(clip, port)
        with seen:
            assert seen.wait_for(lambda: len(frames) > before + 2, 60), "the stream did not come back"
        assert states[-1] == "running"
    finally:
        source.close()
        sender.kill()
        sender.wait(10)
        reader.join(30)


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed (apt-get install ffmpeg)")
def test_the_rtp_whitelist_is_set_for_the_stream_only(monkeypatch) -> None:
    """FFmpeg's protocol whitelist (needed to follow the SDP file to UDP) is not left set for the process: a
    later capture of another kind (an RTSP camera over TCP) would be refused by it."""
    monkeypatch.delenv("OPENCV_FFMPEG_CAPTURE_OPTIONS", raising=False)
    port = free_udp_port()
    sender = stream_rtp(shared_file("aquarium_fish/fish.mp4"), port)
    source = StreamSource(SourceConfig(uri=f"udp://127.0.0.1:{port}", fps=5))
    try:
        frame = next(iter(source))
        assert frame.image.ndim == 3  # the stream opened: the whitelist was in force while it did
        assert "OPENCV_FFMPEG_CAPTURE_OPTIONS" not in os.environ
    finally:
        source.close()
        sender.kill()
        sender.wait(10)


def test_a_failure_names_the_source_once() -> None:
    details: list[str] = []

    def opener() -> FrameSource:
        raise MerlionError("source cam: no such file or folder")

    def on_state(state: str, detail: str) -> None:
        if state == "retrying":
            details.append(detail)
            source.close()

    source = RetryingSource(opener, name="cam", live=False, initial_s=0.01, max_s=0.01, on_state=on_state)
    assert list(source) == []
    assert details == ["no such file or folder"] and source.last_error == "no such file or folder"
