"""File and folder sources on real video: subsampling, traceable indices, loss counting on damaged copies."""

from __future__ import annotations

import struct

import cv2
import pytest

from companion.config import SourceConfig
from companion.errors import MerlionError
from companion.sources.factory import open_source
from companion.sources.folder import FolderSource, natural_key
from companion.sources.subsample import RateSubsampler
from companion.sources.video import VideoSource
from tests.conftest import run_merlion, shared_file

SURVEY = "survey/survey_480x270.mp4"  # 93 frames, 10 fps, H.264, moov atom after the data


def _atoms(buf, start, end):
    pos = start
    while pos + 8 <= end:
        size, kind = struct.unpack(">I4s", buf[pos:pos + 8])
        header = 8
        if size == 1:
            size, header = struct.unpack(">Q", buf[pos + 8:pos + 16])[0], 16
        elif size == 0:
            size = end - pos
        yield kind.decode("latin-1"), pos, header, size
        pos += size


def _shift_chunk_offsets(buf, start, end, delta):
    for kind, pos, header, size in _atoms(buf, start, end):
        if kind in ("trak", "mdia", "minf", "stbl"):
            _shift_chunk_offsets(buf, pos + header, pos + size, delta)
        elif kind in ("stco", "co64"):
            body = pos + header
            count = struct.unpack(">I", buf[body + 4:body + 8])[0]
            fmt, width = (">I", 4) if kind == "stco" else (">Q", 8)
            for i in range(count):
                at = body + 8 + i * width
                struct.pack_into(fmt, buf, at, struct.unpack(fmt, buf[at:at + width])[0] + delta)


def faststart(data: bytes) -> bytes:
    """Move the moov atom before the media data (as `ffmpeg -movflags faststart` does), so a truncated copy
    still announces every frame and the decoder can read the part that survived."""
    top = list(_atoms(data, 0, len(data)))
    ftyp = next(a for a in top if a[0] == "ftyp")
    moov = next(a for a in top if a[0] == "moov")
    mbuf = bytearray(data[moov[1]:moov[1] + moov[3]])
    _shift_chunk_offsets(mbuf, moov[2], len(mbuf), len(mbuf))
    rest = b"".join(data[p:p + s] for k, p, _, s in top if k not in ("moov", "ftyp"))
    return data[ftyp[1]:ftyp[1] + ftyp[3]] + bytes(mbuf) + rest


def test_rate_subsampler_keeps_a_grid():
    sub = RateSubsampler(5.0)
    assert [i for i in range(12) if sub.keep(i / 10.0)] == [0, 2, 4, 6, 8, 10]
    sub = RateSubsampler(5.0)
    assert [i for i in range(7) if sub.keep(i / 3.0)] == list(range(7))


def test_video_subsampled_to_fps_keeps_source_index_and_time():
    src = VideoSource(shared_file(SURVEY), fps=5)
    frames = list(src)
    assert src.source_fps == pytest.approx(10.0) and src.frame_count == 93
    assert [f.index for f in frames] == list(range(0, 93, 2))
    assert all(f.time_s == pytest.approx(f.index / 10.0) for f in frames)
    assert frames[0].image.shape == (270, 480, 3) and frames[0].image.dtype.name == "uint8"
    assert src.lost == 0


def test_video_faster_than_source_keeps_every_frame():
    frames = list(VideoSource(shared_file(SURVEY), fps=30))
    assert [f.index for f in frames] == list(range(93))


def test_hevc_clip_decodes():
    src = VideoSource(shared_file("rov_clips/V4361_20211006T162656Z_h265_1sec.mp4"), fps=5)
    frames = list(src)  # 32 frames at 59.94 fps: 0.53 s
    assert [f.index for f in frames] == [0, 12, 24]
    assert frames[0].image.shape[:2] == (1080, 1920) and src.lost == 0


def test_truncated_video_yields_what_survives_and_counts_the_loss(tmp_path):
    whole = faststart(shared_file(SURVEY).read_bytes())
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(whole[: int(len(whole) * 0.6)])
    src = VideoSource(cut, fps=100)
    frames = list(src)
    assert 10 < len(frames) < 93
    assert src.lost == 93 - len(frames)
    assert [f.index for f in frames] == list(range(len(frames)))


def test_video_with_nothing_readable_fails_with_one_line(tmp_path):
    cut = tmp_path / "cut.mp4"
    data = shared_file(SURVEY).read_bytes()
    cut.write_bytes(data[: len(data) // 2])  # the index (moov) is at the end: nothing can be decoded
    with pytest.raises(MerlionError) as err:
        list(VideoSource(cut))
    assert str(cut) in str(err.value) and "\n" not in str(err.value)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"not a video at all" * 100)
    with pytest.raises(MerlionError):
        list(VideoSource(junk))


def test_a_file_that_is_not_a_video_gets_our_one_line_and_nothing_from_ffmpeg(tmp_path):
    """FFmpeg writes "moov atom not found" (and OpenCV its own warning) from C, straight to stderr: the real
    command's stderr must hold our line alone; an operator who asks for FFmpeg's level still gets its lines."""
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"not a video at all" * 100)
    done = run_merlion("summarize", str(junk), "-o", str(tmp_path / "out"), timeout=120)
    assert done.returncode != 0
    assert done.stderr.splitlines() == [f"merlion: error: {junk}: cannot be opened as a video (unknown format, or "
                                        "damaged beyond reading)"]
    assert "moov" not in done.stdout
    loud = run_merlion("summarize", str(junk), "-o", str(tmp_path / "out"), timeout=120,
                       env={"OPENCV_FFMPEG_LOGLEVEL": "16"})
    assert "moov atom not found" in loud.stdout + loud.stderr  # through OpenCV's callback, which prints to stdout
    assert loud.stderr.splitlines()[-1].startswith("merlion: error: ")


def test_video_loops_with_increasing_indices():
    src = VideoSource(shared_file(SURVEY), fps=5, loop=True)
    frames = []
    for frame in src:
        frames.append(frame)
        if len(frames) == 60:
            break
    src.close()
    assert frames[47].index == 93 + 0 and frames[47].time_s == pytest.approx(9.3)
    assert all(a.time_s < b.time_s for a, b in zip(frames, frames[1:], strict=False))


def test_natural_sort():
    names = ["f10.png", "f2.png", "F1.png", "f1b.png"]
    assert sorted(names, key=natural_key) == ["F1.png", "f1b.png", "f2.png", "f10.png"]


@pytest.fixture
def image_folder(tmp_path):
    frames = list(VideoSource(shared_file(SURVEY), fps=2))[:4]
    for i, frame in zip((1, 2, 10, 11), frames, strict=True):
        cv2.imwrite(str(tmp_path / f"frame{i}.jpg"), frame.image)
    (tmp_path / "frame3.jpg").write_bytes(b"broken")
    (tmp_path / "notes.txt").write_text("ignored")
    return tmp_path


def test_folder_in_natural_order_counts_unreadable(image_folder):
    src = FolderSource(image_folder, fps=5)
    frames = list(src)
    assert len(frames) == 4 and src.lost == 1
    assert [f.index for f in frames] == [0, 1, 3, 4]  # frame3.jpg (index 2) could not be read
    assert [f.time_s for f in frames] == pytest.approx([0.0, 0.2, 0.6, 0.8])


def test_empty_folder_is_an_error(tmp_path):
    with pytest.raises(MerlionError, match="no images"):
        FolderSource(tmp_path)


def test_factory_dispatches_on_the_uri(image_folder, tmp_path):
    assert isinstance(open_source(SourceConfig(uri=str(image_folder)), realtime=False), FolderSource)
    video = open_source(SourceConfig(uri=f"file://{shared_file(SURVEY)}", fps=2), realtime=False)
    assert isinstance(video, VideoSource) and not video.realtime and video.fps == 2
    with pytest.raises(MerlionError, match="no such file"):
        open_source(SourceConfig(uri=str(tmp_path / "missing.mp4")))


def test_video_closed_from_another_thread_while_reading_stops_the_reader():
    """The live companion closes the source from its main thread while the capture thread is inside the
    decoder; releasing the capture under a grab hung the process (seen in `merlion run` with a looping file)."""
    import random
    import threading

    path = shared_file("survey/survey_480x270.mp4")
    rng = random.Random(7)
    for _ in range(12):
        src = VideoSource(path, fps=1000, realtime=False, loop=True)
        seen, errors = [], []

        def read(src=src, seen=seen, errors=errors):
            try:
                for frame in src:
                    seen.append(frame.index)
            except Exception as err:  # noqa: BLE001 - the test reports it
                errors.append(err)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        threading.Event().wait(rng.uniform(0.0, 0.15))
        src.close()
        reader.join(10)
        assert not reader.is_alive() and errors == []
        assert seen == sorted(seen)
        assert src._cap is None
