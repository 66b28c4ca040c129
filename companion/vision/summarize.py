"""``merlion summarize``: run a whole video or folder through the pipeline and write the summary to a directory.

The output directory holds ``summary.json`` (source, encoder, parameters, and the summary frames in time order;
a topic that no frame passed shows its best-scoring frames instead, each marked ``below_threshold``),
the frames at full resolution under ``frames/`` and ``contact_sheet.jpg``. With several topics
(``queries.topics``) each topic's frames go under ``frames/<topic>/`` with a ``contact_sheet_<topic>.jpg`` each,
and every frame entry names its topic. It is built in a temporary sibling
directory and moved into place at the end, so a failure never leaves a half-written summary, and an existing
directory is replaced only when the caller says ``force``.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2

from companion.config import Config
from companion.errors import MerlionError, UsageError
from companion.sources.base import FrameSource
from companion.sources.factory import open_source
from companion.sources.folder import FolderSource
from companion.sources.frame_feed import FrameFeed
from companion.vision import progress_lines
from companion.vision.contact_sheet import Tile, contact_sheet
from companion.vision.encoders.base import Encoder
from companion.vision.encoders.factory import make_encoder
from companion.vision.events import SummaryFrame
from companion.vision.feedback import read_mark_images, with_marks
from companion.vision.pipeline import FrameResult, Pipeline

log = logging.getLogger(__name__)

JPEG_QUALITY = 95


@dataclass
class SummaryRun:
    """What a summarize run produced, for the command's closing line and for tests."""

    out_dir: Path
    document: dict
    frames_seen: int
    frames_passed: int
    frames_lost: int
    stills: bool = False
    """The source was an image folder: frames are images, ``frames_lost`` unreadable ones."""
    source_fps: float | None = None
    """A video's own frame rate: ``frames_lost`` counts frames at this rate, ``frames_seen`` at the kept rate."""


def expected_frames(source: FrameSource) -> int | None:
    """About how many frames a file or folder source will yield (for the progress bar), or None if unknown."""
    count = getattr(source, "frame_count", 0)
    src_fps, fps = getattr(source, "source_fps", 0.0), getattr(source, "fps", 0.0)
    if count and src_fps and fps:
        return math.ceil(count * min(1.0, fps / src_fps))
    files = getattr(source, "files", None)
    return len(files) if files is not None else None


def frame_file_name(frame: SummaryFrame) -> str:
    return f"frame_{frame.frame_index:06d}.jpg"


def frame_file(frame: SummaryFrame, several_topics: bool) -> str:
    """Where a summary frame is written, relative to the output directory (a frame may be in two topics)."""
    if several_topics:
        return f"frames/{frame.topic}/{frame_file_name(frame)}"
    return f"frames/{frame_file_name(frame)}"


def sheet_name(topic: str, several_topics: bool) -> str:
    return f"contact_sheet_{topic}.jpg" if several_topics else "contact_sheet.jpg"


def _check_out_dir(out_dir: Path, force: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"{out_dir}: exists and is not a directory")
    if out_dir.exists() and not force:
        raise UsageError(f"{out_dir}: already exists; use --force to replace it")
    parent = out_dir.parent
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"{out_dir}: {parent} is a file, not a folder")
    if not parent.is_dir():
        raise UsageError(f"{out_dir}: parent directory {parent} does not exist")




def build_document(cfg: Config, encoder: Encoder, pipeline: Pipeline, frames: list[SummaryFrame],
                   stats: dict, origin: Callable[[int], str | None] | None = None) -> dict:
    """summary.json: the issue's schema, frames in time order (with several topics, the topics' frames together,
    each naming its topic; ``params.topics`` describes every topic). ``origin``: the source file of a frame index
    (an image folder's stills), written as each frame's ``source``."""
    several = len(pipeline.topics) > 1
    topics = [{"name": t.name, "query": t.presampler.positive, "negatives": t.presampler.negatives,
               "tau_ss": t.presampler.tau_ss, "frames": sum(f.topic == t.name for f in frames),
               "below_threshold": any(f.topic == t.name and f.below_threshold for f in frames),
               "contact_sheet": sheet_name(t.name, several)} for t in pipeline.topics]
    return {
        "source": cfg.source.uri,
        "encoder": encoder.name,
        "params": {
            "k": pipeline.sampler.k,
            "query": pipeline.presampler.positive,
            "negatives": pipeline.presampler.negatives,
            "tau_ss": pipeline.presampler.tau_ss,
            "distance": pipeline.sampler.distance,
            "threshold": pipeline.sampler.threshold,
            "fps": cfg.source.fps,
            "enhance": cfg.enhance.mode,
            "tau_ses": pipeline.tau_ses if cfg.enhance.mode == "selective" else None,
            "gate": cfg.gate.model_dump(),
            "encoder": encoder.describe(),
            "stats": stats,
            "topics": topics,
            "short": short_notes(topics, pipeline.sampler.k),
        },
        "frames": [_frame_entry(f, several, origin)
                   for f in sorted(frames, key=lambda f: (f.time_s, f.frame_index, f.topic))],
    }


def _frame_entry(f: SummaryFrame, several: bool, origin: Callable[[int], str | None] | None) -> dict:
    entry = {"index": f.frame_index, "time_s": round(f.time_s, 4), "score": round(float(f.score), 6),
             "raw_score": None if f.raw_score is None else round(float(f.raw_score), 6),
             "file": frame_file(f, several), "topic": f.topic, "below_threshold": f.below_threshold}
    name = origin(f.frame_index) if origin is not None else None
    if name is not None:
        entry["source"] = name  # a still: its own file, the one thing that finds it again (its time is made up)
    return entry


def plural(n: int, noun: str) -> str:
    """``1 frame``, ``2 frames``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def short_notes(topics: list[dict], k: int) -> list[str]:
    """One sentence per topic holding fewer than K frames: the dive had fewer distinct views that passed the
    query (duplicates never take a place), so the summary is smaller rather than padded with copies; or nothing
    passed at all, and the few frames shown are the best ones below the threshold."""
    notes = []
    for t in topics:
        if t["below_threshold"]:
            notes.append(f"{t['name']}: nothing passed the query; the {plural(t['frames'], 'best frame')} "
                         f"{'is' if t['frames'] == 1 else 'are'} kept, marked below the threshold")
        elif t["frames"] < k:
            notes.append(f"{t['name']}: {t['frames']} of K={k} frames, the video has no more distinct views that "
                         f"passed the query")
    return notes


def _write(out_tmp: Path, document: dict, frames: list[SummaryFrame]) -> None:
    topics = document["params"]["topics"]
    several = len(topics) > 1
    (out_tmp / "frames").mkdir()
    for f in frames:
        path = out_tmp / frame_file(f, several)
        path.parent.mkdir(exist_ok=True)
        if not cv2.imwrite(str(path), f.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
            raise MerlionError(f"{path}: could not write the frame")
    for topic in topics:
        ordered = sorted((f for f in frames if f.topic == topic["name"]), key=lambda f: (f.time_s, f.frame_index))
        title = f"{document['source']}  |  {topic['name'] + ': ' if several else ''}{topic['query']}"
        names = {e["index"]: e.get("source") for e in document["frames"] if e["topic"] == topic["name"]}
        tiles = [Tile(f.image, f.time_s, f.score, label=names.get(f.frame_index)) for f in ordered]
        sheet = contact_sheet(tiles, title=title)
        path = out_tmp / topic["contact_sheet"]
        if not cv2.imwrite(str(path), sheet, [cv2.IMWRITE_JPEG_QUALITY, 90]):
            raise MerlionError(f"{path}: could not write the contact sheet")
    (out_tmp / "summary.json").write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def _move_into_place(out_tmp: Path, out_dir: Path) -> None:
    """Put the finished directory where it belongs; an old one (``--force``) goes only once the new one is ready."""
    old = None
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old-{out_tmp.name}")
        out_dir.rename(old)
    try:
        out_tmp.rename(out_dir)
    except OSError:
        if old is not None:
            old.rename(out_dir)  # the previous summary stays where it was
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def summarize(cfg: Config, out_dir: str | Path, *, force: bool = False, encoder: Encoder | None = None,
              progress: bool | None = None, like: Sequence[str | Path] = (),
              unlike: Sequence[str | Path] = (),
              on_results: Callable[[Sequence[FrameResult]], None] | None = None) -> SummaryRun:
    """Summarize ``cfg.source.uri`` into ``out_dir``; raises MerlionError (one line) for anything the user can fix.

    ``like``/``unlike``: marked example images (files or folders) combined with the query score
    (``companion.vision.feedback``); the summary then keeps frames by the combined score.
    ``on_results`` sees every batch's per-frame results (the archive keeps the score over time from it).
    """
    out_dir = Path(out_dir)
    _check_out_dir(out_dir, force)
    try:  # made first, so an output folder that cannot be written fails now, not after the whole video
        out_tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp-", dir=out_dir.parent))
    except OSError as err:
        raise MerlionError(f"{out_dir}: cannot write there ({err.strerror or err})") from None
    try:
        return _summarize_into(cfg, out_dir, out_tmp, encoder, progress, like, unlike, on_results)
    finally:
        if out_tmp.exists():
            shutil.rmtree(out_tmp, ignore_errors=True)


def stills_ungated(cfg: Config, source: FrameSource) -> Config:
    """An image folder's stills are separate photos, not a video's near-identical neighbours: the frame gate (made
    for a slowly moving camera) would skip most of them. It stays off for a folder unless the configuration sets
    ``gate:`` itself."""
    if not isinstance(source, FolderSource) or "gate" in cfg.model_fields_set:
        return cfg
    return cfg.model_copy(update={"gate": cfg.gate.model_copy(update={"mode": "none"})})


def _summarize_into(cfg: Config, out_dir: Path, out_tmp: Path, encoder: Encoder | None,
                    progress: bool | None, like: Sequence[str | Path], unlike: Sequence[str | Path],
                    on_results: Callable[[Sequence[FrameResult]], None] | None = None) -> SummaryRun:
    like_images, unlike_images = read_mark_images(like, "--like"), read_mark_images(unlike, "--unlike")
    source = open_source(cfg.source, realtime=False)
    cfg = stills_ungated(cfg, source)
    if encoder is None:
        encoder = make_encoder(cfg.encoder)
    pipeline = Pipeline.from_config(cfg, encoder)
    # marks teach the default (first) topic: examples of one thing cannot stand for several
    pipeline.presampler = with_marks(pipeline.presampler, like_images, unlike_images)
    seen = passed = 0
    gate = pipeline.gate if pipeline.gate.on else None  # gated in the decode thread: full batches to encode
    with FrameFeed(source, pipeline.prepare, gate=gate) as feed, \
            progress_lines.progress("summarize", "frame", expected_frames(source), progress) as bar:
        for batch in feed.batches(cfg.encoder.batch):
            out = pipeline.process([f for f, _ in batch], [s for _, s in batch], gated=feed.gated)
            seen += len(batch)
            passed += sum(r.passed for r in out.results)
            if on_results is not None:
                on_results(out.results)
            bar.set_postfix(passed=passed, held=len(pipeline.summary))
            bar.update(len(batch))
    stand_ins = pipeline.finish()  # a topic nothing passed for shows its best frames, marked below threshold
    if stand_ins:
        log.warning("no frame passed tau_ss for topic(s) %s: the best-scoring frames are kept, marked "
                    "below_threshold", ", ".join(sorted({e.frame.topic for e in stand_ins if e.kind == "added"})))
    lost = int(getattr(source, "lost", 0))
    if lost:
        log.warning("%s: %s could not be decoded and %s skipped", cfg.source.uri, plural(lost, "frame"),
                    "was" if lost == 1 else "were")
    frames = pipeline.summary
    stats = {"frames_seen": seen, "frames_passed": passed, "frames_lost": lost,
             "frames_added": pipeline.counts["added"], "frames_encoded": pipeline.counts["encoded"],
             "frames_skipped": pipeline.counts["skipped"], "frames_duplicate": pipeline.counts["duplicates"],
             "encoder_images": pipeline.clock.items.get("encode", 0) + pipeline.clock.items.get("reencode", 0)}
    document = build_document(cfg, encoder, pipeline, frames, stats, origin=source.origin)
    if like or unlike:
        document["params"]["marks"] = {"like": [str(p) for p in like], "unlike": [str(p) for p in unlike]}
    try:
        _write(out_tmp, document, frames)
        _move_into_place(out_tmp, out_dir)
    except OSError as err:
        raise MerlionError(f"{out_dir}: cannot write the summary ({err.strerror or err})") from None
    return SummaryRun(out_dir, document, seen, passed, lost, stills=isinstance(source, FolderSource),
                      source_fps=getattr(source, "source_fps", None))
