"""``merlion bench pipeline``: is the whole vision core as fast as its encoder, and is the sampler negligible?

One run measures, on the same frames of one source:

- as the user feels it: ``video_fps``, source frames handled per second end to end (the frames the gate skipped
  included, ``gate:`` of the configuration), and ``encoder_calls``, how many of them the encoder saw;
- end to end: decode (in the feed thread), gate, downscale, encode, score, pre-sample and sample, in frames
  encoded per second (``end_to_end_fps``; equal to ``video_fps`` with the gate off);
- encoder only: the same downscaled frames through ``encode_images`` at the same batch size, frames/s;
- the sampler alone at K = 6 and K = 64: milliseconds per offered frame over a long seeded stream of features
  with the encoder's dimension (a real dive has too few frames to fill K = 64 many times over);
- the peak resident memory of the process: after the encoder was built (``load_peak_rss_mb``), over loading and
  the end-to-end run (``peak_rss_mb``, the kernel's VmHWM), and resident after that run (``steady_rss_mb``),
  all read before the encoder-only pass, which holds ``frames`` decoded frames that the companion never holds
  (it grew the peak with ``--frames``: +44 MB from 16 to 64 frames); the peaks of the encoder's short-lived
  torch child processes apart, in ``child_peak_rss_mb``;
- the paper's own per-frame loop as the baseline (``paper_frames`` frames): read a frame, open_clip's own PIL
  transform on the full frame, the model at batch 1 in fp32, score, sampler, no decode thread. Our end-to-end
  rate divided by it is ``speedup_vs_paper_loop``: a ratio measured in the same run on the same machine, so it
  survives the machine's noise and slowness where absolute frames/s do not. For a non-CLIP encoder the baseline
  is the same batch-1 loop with that encoder fed full frames. It runs last, after the peak RSS was read, since a
  reduced-precision run needs a second, fp32 copy of the model for it. ``video_speedup_vs_paper_loop`` is
  ``video_fps`` over it: how much more of the camera's stream the gated pipeline keeps up with.

The source is looped until ``frames`` frames have gone through, so a short clip still gives a steady rate.
Speed targets are checked here, never in tests.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
import psutil
from tqdm import tqdm

from companion.config import Config
from companion.sources.factory import open_source
from companion.sources.frame_feed import FrameFeed
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.factory import make_encoder
from companion.vision.encoders.peak_rss import peak_rss_mb
from companion.vision.pipeline import Pipeline
from companion.vision.presampler import PreSampler
from companion.vision.sampler import InformativeSampler

SAMPLER_FRAMES = 3000
SAMPLER_SEED = 20240607


@dataclass
class PipelineBench:
    encoder: dict
    source: str
    frames: int
    batch: int
    end_to_end_fps: float
    encoder_fps: float
    sampler_ms_k6: float
    sampler_ms_k64: float
    peak_rss_mb: float
    load_peak_rss_mb: float
    """Peak RSS right after the encoder was built: how much of the peak is the weights' loading."""
    rss_end_mb: float
    """Resident memory at the end of the run (steady state, after loading transients are gone)."""
    stage_ms: dict
    decode_ms: float
    passed: int
    video_fps: float = 0.0
    """Source frames handled per second end to end, the ones the gate skipped included."""
    encoder_calls: int = 0
    """Frames of the end-to-end run that the encoder saw (the gate let them through)."""
    gate: dict | None = None
    paper_loop_fps: float | None = None
    """The paper's per-frame loop (batch 1, fp32, open_clip's PIL transform, no decode thread) on the same source."""
    paper_loop_frames: int = 0
    paper_loop_precision: str | None = None
    cpu_ms: dict | None = None
    """Process CPU ms per frame of each phase (end_to_end, encoder, paper_loop): less swayed than wall time by
    other processes on a shared machine, so their ratios are the steadier comparison."""
    child_peak_rss_mb: dict | None = None
    """Peak RSS of each short-lived torch child process the encoder ran (ONNX runtime: "export" at a first start,
    "texts" for queries not in the cache), each its own process: not part of ``peak_rss_mb``, reported apart."""

    def _cpu_ratio(self, slow: str, fast: str) -> float | None:
        cpu = self.cpu_ms or {}
        return cpu[slow] / cpu[fast] if cpu.get(slow) and cpu.get(fast) else None

    @property
    def speedup_vs_paper_loop(self) -> float | None:
        return self.end_to_end_fps / self.paper_loop_fps if self.paper_loop_fps else None

    @property
    def video_speedup_vs_paper_loop(self) -> float | None:
        return self.video_fps / self.paper_loop_fps if self.paper_loop_fps else None

    def as_json(self) -> dict:
        return {"video_fps": round(self.video_fps, 2), "encoder_calls": self.encoder_calls, "gate": self.gate,
                "video_speedup_vs_paper_loop": _round(self.video_speedup_vs_paper_loop, 3),
                "end_to_end_fps": round(self.end_to_end_fps, 2), "encoder_fps": round(self.encoder_fps, 2),
                "sampler_ms_k6": round(self.sampler_ms_k6, 4), "sampler_ms_k64": round(self.sampler_ms_k64, 4),
                "peak_rss_mb": round(self.peak_rss_mb, 1), "load_peak_rss_mb": round(self.load_peak_rss_mb, 1),
                "rss_end_mb": round(self.rss_end_mb, 1), "steady_rss_mb": round(self.rss_end_mb, 1),
                "child_peak_rss_mb": self.child_peak_rss_mb or {},
                "frames": self.frames, "batch": self.batch,
                "encoder": self.encoder, "source": self.source,
                "stage_ms_per_frame": {k: round(v, 3) for k, v in self.stage_ms.items()},
                "decode_ms_per_frame": round(self.decode_ms, 3),
                "paper_loop_fps": None if self.paper_loop_fps is None else round(self.paper_loop_fps, 3),
                "speedup_vs_paper_loop": (None if self.speedup_vs_paper_loop is None
                                          else round(self.speedup_vs_paper_loop, 3)),
                "paper_loop_frames": self.paper_loop_frames, "paper_loop_precision": self.paper_loop_precision,
                "cpu_ms_per_frame": {k: round(v, 2) for k, v in (self.cpu_ms or {}).items()},
                "cpu_speedup_vs_paper_loop": _round(self._cpu_ratio("paper_loop", "end_to_end"), 3),
                "cpu_video_speedup_vs_paper_loop": _round(self._cpu_ratio("paper_loop", "video"), 3)}

    def table(self) -> str:
        ratio = self.end_to_end_fps / self.encoder_fps if self.encoder_fps else float("nan")
        rows = [
            ("encoder", f"{self.encoder.get('name')} {self.encoder.get('precision', '')} batch {self.batch}"),
            ("frames", f"{self.frames} from {self.source} ({self.passed} passed the query)"),
            ("video", f"{self.video_fps:.1f} source frames/s, {self.encoder_calls} of {self.frames} encoded "
                      f"(gate {_gate_text(self.gate)})"),
            ("end to end", f"{self.end_to_end_fps:.1f} encoded frames/s ({ratio:.2f} x encoder only)"),
            ("encoder only", f"{self.encoder_fps:.1f} frames/s"),
            ("sampler K=6", f"{self.sampler_ms_k6:.3f} ms/frame"),
            ("sampler K=64", f"{self.sampler_ms_k64:.3f} ms/frame"),
            ("peak RSS", f"{self.peak_rss_mb:.0f} MB ({self.load_peak_rss_mb:.0f} MB peak after loading the "
                         f"encoder, {self.rss_end_mb:.0f} MB resident after the run)"
                         + "".join(f"; {k} child {v:.0f} MB" for k, v in (self.child_peak_rss_mb or {}).items())),
            ("stages", ", ".join(f"{k} {v:.2f}" for k, v in self.stage_ms.items()) + " ms/frame"),
            ("decode thread", f"{self.decode_ms:.2f} ms/frame"),
        ]
        if self.cpu_ms:
            cpu = ", ".join(f"{k.replace('_', ' ')} {v:.0f}" for k, v in self.cpu_ms.items())
            vs = self._cpu_ratio("paper_loop", "end_to_end")
            than = "" if not vs else (f" ({vs:.2f} x less than the paper's loop)" if vs >= 1
                                      else f" ({1 / vs:.2f} x more than the paper's loop)")
            rows.append(("CPU time", f"{cpu} ms/frame{than}"))
        if self.paper_loop_fps:
            rows.insert(5, ("paper loop", f"{self.paper_loop_fps:.2f} frames/s ({self.paper_loop_frames} frames, "
                                          f"batch 1, {self.paper_loop_precision}, its own preprocessing): the "
                                          f"video goes {self.video_speedup_vs_paper_loop:.2f} x, end to end "
                                          f"{self.speedup_vs_paper_loop:.2f} x the paper's loop"))
        return "\n".join(f"{name:<14}{value}" for name, value in rows)


def _gate_text(gate: dict | None) -> str:
    if not gate or gate.get("mode") == "none":
        return "off"
    return f"difference > {gate['threshold']:g}, max gap {gate['max_gap_s']:g} s"


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def rss_now_mb() -> float:
    return psutil.Process().memory_info().rss / (1024.0 * 1024.0)


def sampler_ms_per_frame(k: int, dim: int, frames: int = SAMPLER_FRAMES, distance: str = "js",
                         threshold: str = "mean") -> float:
    """Mean milliseconds per offered frame (preparing the feature included) over a seeded random stream."""
    rng = np.random.default_rng(SAMPLER_SEED)
    stream = rng.standard_normal((frames, dim)).astype(np.float32)
    sampler = InformativeSampler(k, distance, threshold)
    start = time.perf_counter()
    for key, row in enumerate(stream):
        sampler.offer(key, row)
    return 1000.0 * (time.perf_counter() - start) / frames


def _looped(cfg: Config) -> Config:
    looped = cfg.model_copy(deep=True)
    looped.source.loop = True
    looped.source.realtime = False
    return looped


def _fp32_twin(cfg: Config, encoder: Encoder) -> Encoder:
    """The encoder itself when it runs torch in fp32 (or has no precision), else a fresh torch fp32 one of the same
    model: the paper's loop is the baseline, so it never runs through ONNX Runtime or a reduced precision."""
    described = encoder.describe()
    if described.get("precision", "fp32") == "fp32" and described.get("runtime", "torch") == "torch":
        return encoder
    return make_encoder(cfg.encoder.model_copy(update={"precision": "fp32", "runtime": "torch", "batch": 1}))


def paper_loop_fps(cfg: Config, encoder: Encoder, frames: int, *,
                   progress: bool = False) -> tuple[float, str, float]:
    """Frames/s, precision and CPU ms per frame of the paper's loop: decode, preprocess, encode at batch 1, score and sample, one frame at a time.

    CLIP gets open_clip's own PIL transform on the full frame (``encode_images_reference``); other encoders get
    the full frame through ``encode_images``. The first frame is a warm-up and is not timed.
    """
    paper = _fp32_twin(cfg, encoder)
    reference = getattr(paper, "encode_images_reference", None)
    encode = reference if reference is not None else paper.encode_images
    presampler = PreSampler(paper, cfg.queries.positive, cfg.queries.negatives, cfg.queries.tau_ss)
    sampler = InformativeSampler(cfg.sampler.k, cfg.sampler.distance, cfg.sampler.threshold)
    source = open_source(_looped(cfg).source)
    done, start, cpu_start = 0, None, 0.0
    try:
        with tqdm(total=frames, desc="paper loop", unit="frame", file=sys.stderr, disable=not progress) as bar:
            for frame in source:
                emb = encode([frame.image])
                pooled = paper.sampler_features(emb)
                score = presampler.scores(emb, pooled=pooled)
                if presampler.passes(score)[0]:
                    sampler.offer(frame.index, pooled[0])
                if start is None:
                    start, cpu_start = time.perf_counter(), time.process_time()
                    continue
                done += 1
                bar.update(1)
                if done >= frames:
                    break
    finally:
        source.close()
    precision = str(paper.describe().get("precision", "-"))
    if start is None or done == 0:
        return 0.0, precision, 0.0
    return (done / (time.perf_counter() - start), precision,
            1000.0 * (time.process_time() - cpu_start) / done)


def _decoded(cfg: Config, pipeline: Pipeline, frames: int) -> list[np.ndarray]:
    """The first ``frames`` frames of the (looped) source, downscaled as the pipeline feeds its encoder."""
    prepared: list[np.ndarray] = []
    with FrameFeed(open_source(cfg.source), pipeline.prepare, limit=frames) as feed:
        for chunk in feed.batches(frames):
            prepared.extend(small for _, small in chunk)
            if len(prepared) >= frames:
                break
    return prepared[:frames]


def bench_pipeline(cfg: Config, *, frames: int = 256, encoder: Encoder | None = None, paper_frames: int = 32,
                   progress: bool = False) -> PipelineBench:
    """Run the measurements; ``cfg`` gives the source, encoder, batch, queries and sampler settings.

    ``paper_frames=0`` skips the paper-loop baseline; ``progress`` draws bars on stderr (for a terminal).
    """
    if encoder is None:
        encoder = make_encoder(cfg.encoder)
    load_peak = peak_rss_mb()
    batch = cfg.encoder.batch
    looped = _looped(cfg)
    pipeline = Pipeline.from_config(looped, encoder)

    encoder.encode_images(_decoded(looped, pipeline, batch))  # warm-up: first-call allocations, kernel choice

    cpu = {}
    cpu_start = time.process_time()
    start = time.perf_counter()
    done = passed = 0
    bar = tqdm(total=frames, desc="end to end", unit="frame", file=sys.stderr, disable=not progress)
    gate = pipeline.gate if pipeline.gate.on else None  # as summarize does: gated in the decode thread
    with bar, FrameFeed(open_source(looped.source), pipeline.prepare, limit=frames, gate=gate) as feed:
        for chunk in feed.batches(batch):
            chunk = chunk[: frames - done]
            out = pipeline.process([f for f, _ in chunk], [s for _, s in chunk], gated=feed.gated)
            done += len(chunk)
            bar.update(len(chunk))
            passed += sum(r.passed for r in out.results)
            if done >= frames:
                break
        decode_ms = 1000.0 * feed.decode_seconds / max(1, feed.decoded)
    elapsed = time.perf_counter() - start
    encoded = pipeline.counts["encoded"]
    end_to_end = encoded / elapsed if encoded else 0.0
    cpu["end_to_end"] = 1000.0 * (time.process_time() - cpu_start) / max(1, encoded)
    cpu["video"] = 1000.0 * (time.process_time() - cpu_start) / max(1, done)
    run_peak, run_rss = peak_rss_mb(), rss_now_mb()

    prepared = _decoded(looped, pipeline, frames)  # the same frames, held for the encoder alone
    cpu_start = time.process_time()
    start = time.perf_counter()
    dims = 0
    for i in range(0, len(prepared), batch):
        emb = encoder.encode_images(prepared[i:i + batch])
        dims = emb.shape[1]
    encoder_only = len(prepared) / (time.perf_counter() - start)
    cpu["encoder"] = 1000.0 * (time.process_time() - cpu_start) / max(1, len(prepared))
    dim = int(encoder.sampler_features(np.zeros((1, dims), np.float32)).shape[1])

    result = PipelineBench(
        encoder=encoder.describe(), source=cfg.source.uri, frames=done, batch=batch,
        end_to_end_fps=end_to_end, encoder_fps=encoder_only, video_fps=done / elapsed, encoder_calls=encoded,
        gate=cfg.gate.model_dump(),
        sampler_ms_k6=sampler_ms_per_frame(6, dim, distance=cfg.sampler.distance, threshold=cfg.sampler.threshold),
        sampler_ms_k64=sampler_ms_per_frame(64, dim, distance=cfg.sampler.distance, threshold=cfg.sampler.threshold),
        peak_rss_mb=run_peak, load_peak_rss_mb=load_peak, rss_end_mb=run_rss,
        stage_ms=pipeline.clock.ms_per_item(), decode_ms=decode_ms, passed=passed, cpu_ms=cpu,
        child_peak_rss_mb=dict(getattr(encoder, "child_peaks_mb", {})),
    )
    if paper_frames > 0:
        fps, precision, cpu_ms = paper_loop_fps(cfg, encoder, paper_frames, progress=progress)
        result.paper_loop_fps, result.paper_loop_precision, result.paper_loop_frames = fps, precision, paper_frames
        if cpu_ms:
            cpu["paper_loop"] = cpu_ms
    return result
