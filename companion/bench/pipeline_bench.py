"""``merlion bench pipeline``: is the whole vision core as fast as its encoder, and is the sampler negligible?

One run measures, on the same frames of one source:

- end to end: decode (in the feed thread), downscale, encode, score, pre-sample and sample, frames/s;
- encoder only: the same downscaled frames through ``encode_images`` at the same batch size, frames/s;
- the sampler alone at K = 6 and K = 64: milliseconds per offered frame over a long seeded stream of features
  with the encoder's dimension (a real dive has too few frames to fill K = 64 many times over);
- the peak resident memory of the process.

The source is looped until ``frames`` frames have gone through, so a short clip still gives a steady rate.
Speed targets are checked here, never in tests.
"""

from __future__ import annotations

import resource
import sys
import time
from dataclasses import dataclass

import numpy as np

from companion.config import Config
from companion.encoders.base import Encoder
from companion.frame_feed import FrameFeed
from companion.pipeline import Pipeline
from companion.sampler import InformativeSampler
from companion.sources.factory import open_source

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

    def as_json(self) -> dict:
        return {"end_to_end_fps": round(self.end_to_end_fps, 2), "encoder_fps": round(self.encoder_fps, 2),
                "sampler_ms_k6": round(self.sampler_ms_k6, 4), "sampler_ms_k64": round(self.sampler_ms_k64, 4),
                "peak_rss_mb": round(self.peak_rss_mb, 1), "load_peak_rss_mb": round(self.load_peak_rss_mb, 1),
                "rss_end_mb": round(self.rss_end_mb, 1), "frames": self.frames, "batch": self.batch,
                "encoder": self.encoder, "source": self.source,
                "stage_ms_per_frame": {k: round(v, 3) for k, v in self.stage_ms.items()},
                "decode_ms_per_frame": round(self.decode_ms, 3)}

    def table(self) -> str:
        ratio = self.end_to_end_fps / self.encoder_fps if self.encoder_fps else float("nan")
        rows = [
            ("encoder", f"{self.encoder.get('name')} {self.encoder.get('precision', '')} batch {self.batch}"),
            ("frames", f"{self.frames} from {self.source} ({self.passed} passed the query)"),
            ("end to end", f"{self.end_to_end_fps:.1f} frames/s ({ratio:.2f} x encoder only)"),
            ("encoder only", f"{self.encoder_fps:.1f} frames/s"),
            ("sampler K=6", f"{self.sampler_ms_k6:.3f} ms/frame"),
            ("sampler K=64", f"{self.sampler_ms_k64:.3f} ms/frame"),
            ("peak RSS", f"{self.peak_rss_mb:.0f} MB ({self.load_peak_rss_mb:.0f} MB peak after loading the "
                         f"encoder, {self.rss_end_mb:.0f} MB resident at the end)"),
            ("stages", ", ".join(f"{k} {v:.2f}" for k, v in self.stage_ms.items()) + " ms/frame"),
            ("decode thread", f"{self.decode_ms:.2f} ms/frame"),
        ]
        return "\n".join(f"{name:<14}{value}" for name, value in rows)


def peak_rss_mb() -> float:
    """Peak resident set of this process (Linux reports KiB, macOS bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def rss_now_mb() -> float:
    import psutil

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


def bench_pipeline(cfg: Config, *, frames: int = 256, encoder: Encoder | None = None) -> PipelineBench:
    """Run the three measurements; ``cfg`` gives the source, encoder, batch, queries and sampler settings."""
    if encoder is None:
        from companion.encoders.factory import make_encoder

        encoder = make_encoder(cfg.encoder)
    load_peak = peak_rss_mb()
    batch = cfg.encoder.batch
    looped = _looped(cfg)
    pipeline = Pipeline.from_config(looped, encoder)

    # the frames, decoded once, for the warm-up and the encoder-only run
    prepared = []
    with FrameFeed(open_source(looped.source), pipeline.prepare, limit=frames) as feed:
        for chunk in feed.batches(batch):
            prepared.extend(small for _, small in chunk)
            if len(prepared) >= frames:
                break
    prepared = prepared[:frames]
    encoder.encode_images(prepared[:batch])  # warm-up: first-call allocations and kernel selection

    start = time.perf_counter()
    done = passed = 0
    with FrameFeed(open_source(looped.source), pipeline.prepare, limit=frames) as feed:
        for chunk in feed.batches(batch):
            chunk = chunk[: frames - done]
            out = pipeline.process([f for f, _ in chunk], [s for _, s in chunk])
            done += len(chunk)
            passed += sum(r.passed for r in out.results)
            if done >= frames:
                break
        decode_ms = 1000.0 * feed.decode_seconds / max(1, feed.decoded)
    end_to_end = done / (time.perf_counter() - start)

    start = time.perf_counter()
    dims = 0
    for i in range(0, len(prepared), batch):
        emb = encoder.encode_images(prepared[i:i + batch])
        dims = emb.shape[1]
    encoder_only = len(prepared) / (time.perf_counter() - start)
    dim = int(encoder.sampler_features(np.zeros((1, dims), np.float32)).shape[1])

    return PipelineBench(
        encoder=encoder.describe(), source=cfg.source.uri, frames=done, batch=batch,
        end_to_end_fps=end_to_end, encoder_fps=encoder_only,
        sampler_ms_k6=sampler_ms_per_frame(6, dim, distance=cfg.sampler.distance, threshold=cfg.sampler.threshold),
        sampler_ms_k64=sampler_ms_per_frame(64, dim, distance=cfg.sampler.distance, threshold=cfg.sampler.threshold),
        peak_rss_mb=peak_rss_mb(), load_peak_rss_mb=load_peak, rss_end_mb=rss_now_mb(), stage_ms=pipeline.clock.ms_per_item(), decode_ms=decode_ms, passed=passed,
    )
