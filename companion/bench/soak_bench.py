"""The soak benchmark: the whole live companion for N minutes at a speed-up, watched from the outside.

The companion runs in this process exactly as ``merlion run`` does (capture, inference, store, surface link),
fed by the generated dive at a higher frame rate than a camera would give, against the simulated ArduSub on a
UDP hub. A ground-station socket on the hub receives what the surface would. Reported:

- frames/s actually scored (by the encoder; frames the gate skipped are counted apart), and frames dropped at
  the input because inference was busy;
- the encoder's own rate during the run (frames encoded over the seconds spent inside the encoder, the figure
  ``bench pipeline`` reports as ``encoder_fps``): ``scored_vs_encoder`` = scored frames/s over it, how much of
  the encoder's rate the live loop keeps (target >= 0.8 with ``--gate none`` and a camera faster than the
  encoder), measured in the same window under the same machine load;
- peak RSS and RSS growth from the end of the first minute (warm-up: model, caches, allocator) to the end
  (target: at most 5%); with runs of a minute or less the first quarter counts as warm-up;
- latency from capture (the frame's wall-clock time, which CAMERA_IMAGE_CAPTURED carries as time_utc) to
  the moment the surface received that message, p50 and p95.

With ``clip_size`` (``--clip 1920x1080``) the generated dive is first rendered to an H.264 file of that size at
``fps`` (ffmpeg; drawn at 640x360 and scaled, since drawing 1080p runs at ~8 frames/s here), and the companion
plays that file in real time, looped: the live path from a file or stream at a camera's resolution, decode
included. Beside the drops, the file's decode rate alone is measured in the same process right after the run
(``decode_fps``, frames/s decoded flat out, and ``decode_vs_source``, that over ``fps``): a run that drops frames
while the decoder keeps ~1x the source rate or less is decode bound, not held up by the pipeline.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import psutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import build_config
from companion.live.companion import LiveCompanion, LiveOptions
from companion.live.udp_hub import UdpHub
from companion.sources.synthetic import SyntheticSource
from companion.sources.video import VideoSource
from vehicle.sim.ground_listener import GroundListener
from vehicle.sim.vehicle import SimVehicle

log = logging.getLogger(__name__)

CAPTURED = "CAMERA_IMAGE_CAPTURED"


@dataclass
class SoakResult:
    minutes: float
    encoder: str
    source_fps: float
    frames_seen: int = 0
    frames_scored: int = 0
    frames_skipped: int = 0
    frames_dropped: int = 0
    scored_fps: float = 0.0
    encoder_fps: float = 0.0
    scored_vs_encoder: float | None = None
    gate: str = ""
    stage_ms: dict = field(default_factory=dict)
    """Milliseconds per item of each pipeline stage during the run (where the inference thread's time went)."""
    summary_added: int = 0
    captures_received: int = 0
    rss_start_mb: float = 0.0
    rss_after_warmup_mb: float = 0.0
    rss_end_mb: float = 0.0
    peak_rss_mb: float = 0.0
    rss_growth_pct: float = 0.0
    warmup_s: float = 60.0
    latency_p50_s: float | None = None
    latency_p95_s: float | None = None
    inference_errors: int = 0
    rss_samples: list[tuple[float, float]] = field(default_factory=list)
    source: str = "synthetic"
    """What the companion read: the generated dive drawn live, or the file rendered from it (``WxH file``)."""
    dropped_pct: float = 0.0
    """Frames dropped at the input, in percent of the frames seen."""
    dropped_after_warmup: int = 0
    """Of those, the ones dropped after the warm-up (the encoder's first slow batches, and the gate admitting
    the first twenty frames all, fall in it)."""
    decode_fps: float | None = None
    """The clip decoded flat out, frames/s, measured in this process after the run (``clip_size`` only)."""
    decode_vs_source: float | None = None
    """``decode_fps`` over the source's rate: at ~1 or below, the run is decode bound."""
    admit_ms: float | None = None
    """Milliseconds per frame the capture thread spent gating and downscaling (off the inference thread)."""


CLIP_SECONDS = 2.0
"""Seconds per segment of the rendered clip (five segments: a 10-s file, looped)."""
DRAW_SIZE = (640, 360)
"""The size the clip's frames are drawn at before ffmpeg scales them (drawing is the slow part)."""


def render_clip(path: Path, size: tuple[int, int], fps: float) -> Path:
    """The generated dive (five segments) as an H.264 MP4 of ``size`` at ``fps``, what a camera recorder gives."""
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise RuntimeError("bench soak --clip needs ffmpeg on PATH (apt-get install ffmpeg)")
    w, h = DRAW_SIZE
    uri = f"synthetic://dive?seconds={CLIP_SECONDS:g}&width={w}&height={h}&segments=5"
    cmd = [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "bgr24", "-s", f"{w}x{h}",
           "-r", f"{fps:g}", "-i", "-", "-vf", f"scale={size[0]}:{size[1]}", "-c:v", "libx264", "-preset",
           "veryfast", "-pix_fmt", "yuv420p", "-g", str(int(fps)), str(path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE)
    try:
        for frame in SyntheticSource(uri, fps=fps, realtime=False, width=w, height=h):
            proc.stdin.write(frame.image.tobytes())
    finally:
        proc.stdin.close()
        if proc.wait(timeout=300) != 0:
            raise RuntimeError(f"ffmpeg could not write {path}")
    return path


def decode_rate(path: Path, frames: int = 600) -> float:
    """Frames/s the file decodes at flat out (OpenCV's FFmpeg, as the companion reads it), up to ``frames``."""
    source = VideoSource(path, fps=1000.0, realtime=False, loop=True)
    n, start = 0, time.perf_counter()
    try:
        for _ in source:
            n += 1
            if n >= frames:
                break
    finally:
        source.close()
    return n / max(time.perf_counter() - start, 1e-9)


def capture_latencies(captured: list[mav.MAVLink_message]) -> list[float]:
    """Seconds from capture (time_utc) to arrival at the surface, per image index; a re-sent capture is not a new
    latency."""
    seen: set[int] = set()
    out = []
    for m in captured:
        if m.image_index not in seen:
            seen.add(m.image_index)
            out.append(m.received_at - m.time_utc / 1e6)
    return out


def encoder_rate(companion: LiveCompanion) -> float:
    """Frames/s of the encoder itself during the run: frames encoded over the seconds spent inside the encoder.

    Taken from the pipeline's stage clock in the same window as the scored rate, so both see the same machine
    load (a separate encoder-only pass before or after the run would not, on a shared machine).
    """
    clock = companion.pipeline.clock
    seconds = clock.seconds.get("encode", 0.0)
    return clock.items.get("encode", 0) / seconds if seconds > 0 else 0.0


def run_soak(minutes: float, *, encoder: str = "auto", fps: float = 15.0, store_dir: str | None = None,
             progress=None, gate: str | None = None, clip_size: tuple[int, int] | None = None) -> SoakResult:
    duration = minutes * 60.0
    warmup = 60.0 if duration > 90.0 else duration / 4
    surface = GroundListener(types=[CAPTURED])
    hub = UdpHub(outputs=[("127.0.0.1", surface.port)]).start()
    sim = SimVehicle(hub.url)
    sim.start()
    tmp = None
    if store_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="merlion-soak-")
        store_dir = tmp.name
    source = {"uri": "synthetic://dive?seconds=4", "fps": fps, "realtime": True}
    clip_dir = None
    if clip_size is not None:
        clip_dir = tempfile.TemporaryDirectory(prefix="merlion-soak-clip-")
        clip = render_clip(Path(clip_dir.name) / f"dive_{clip_size[0]}x{clip_size[1]}.mp4", clip_size, fps)
        source = {"uri": str(clip), "fps": fps, "realtime": True, "loop": True}
    sections = {"gate": {"mode": gate}} if gate else {}
    cfg = build_config({
        **sections,
        "source": source,
        "encoder": {"name": encoder},
        "queries": {"tau_ss": 0.3},
        "mavlink": {"connection": hub.url},
        "surface": {"budget_bytes_per_s": 8000},
        "store": {"dir": str(Path(store_dir))},
        "health": {"stall_after_s": 120.0},
    }, origin="soak")
    proc = psutil.Process()
    result = SoakResult(minutes=minutes, encoder=encoder, source_fps=fps, warmup_s=round(warmup, 1),
                        gate=cfg.gate.mode,
                        source=f"{clip_size[0]}x{clip_size[1]} file" if clip_size else "synthetic")
    result.rss_start_mb = proc.memory_info().rss / 2**20
    companion = LiveCompanion(cfg, LiveOptions())
    try:
        companion.start()
        result.encoder = getattr(companion.encoder, "name", encoder)
        t0 = time.monotonic()
        after_warmup = None
        dropped_at_warmup = 0
        while True:
            elapsed = time.monotonic() - t0
            if elapsed >= duration:
                break
            rss = proc.memory_info().rss / 2**20
            result.rss_samples.append((round(elapsed, 1), round(rss, 1)))
            result.peak_rss_mb = max(result.peak_rss_mb, rss)
            if after_warmup is None and elapsed >= warmup:
                after_warmup = rss
                dropped_at_warmup = companion.queue.dropped
            if progress is not None:
                progress(elapsed, duration, companion.status_line())
            time.sleep(min(1.0, max(0.0, duration - elapsed)))
        companion.stop_pipeline()
        result.dropped_after_warmup = companion.queue.dropped - dropped_at_warmup
        end_rss = proc.memory_info().rss / 2**20
        result.rss_end_mb = end_rss
        result.peak_rss_mb = max(result.peak_rss_mb, end_rss)
        result.rss_after_warmup_mb = after_warmup or end_rss
        companion.drain(10.0)
        time.sleep(0.5)
        result.encoder_fps = round(encoder_rate(companion), 2)
        result.stage_ms = {k: round(v, 2) for k, v in companion.pipeline.clock.ms_per_item().items()}
        admit = getattr(companion.capture, "admit_clock", None)
        if admit is not None and admit[1]:
            result.admit_ms = round(1000.0 * admit[0] / admit[1], 2)
    finally:
        companion.stop()
        sim.stop()
        hub.stop()
        surface.close()
        if tmp is not None:
            tmp.cleanup()
    if clip_dir is not None:
        result.decode_fps = round(decode_rate(Path(source["uri"])), 1)
        result.decode_vs_source = round(result.decode_fps / fps, 2)
        clip_dir.cleanup()
    report = companion.report()
    result.frames_seen = report["frames_seen"]
    result.frames_scored = report["frames_scored"]
    result.frames_skipped = companion.counters.frames_skipped
    result.frames_dropped = report["frames_dropped"]
    result.summary_added = report["summary_added"]
    result.inference_errors = report["inference_errors"]
    result.scored_fps = round(report["frames_scored"] / duration, 2)
    result.dropped_pct = round(100.0 * result.frames_dropped / max(result.frames_seen, 1), 2)
    if result.encoder_fps:
        result.scored_vs_encoder = round(result.scored_fps / result.encoder_fps, 3)
    latencies = capture_latencies(surface.of_type(CAPTURED))
    result.captures_received = len(latencies)
    result.rss_growth_pct = round(100.0 * (result.rss_end_mb - result.rss_after_warmup_mb)
                                  / max(result.rss_after_warmup_mb, 1e-6), 2)
    if latencies:
        lat = np.array(latencies)
        result.latency_p50_s = round(float(np.percentile(lat, 50)), 3)
        result.latency_p95_s = round(float(np.percentile(lat, 95)), 3)
    for key in ("rss_start_mb", "rss_after_warmup_mb", "rss_end_mb", "peak_rss_mb"):
        setattr(result, key, round(getattr(result, key), 1))
    return result


def summary_dict(result: SoakResult) -> dict:
    out = asdict(result)
    out.pop("rss_samples")
    return out
