"""Turn the configured source URI into a frame source: one readable dispatch, one branch per kind of source."""

from __future__ import annotations

from pathlib import Path

from companion.config import SourceConfig
from companion.errors import MerlionError, UsageError
from companion.sources.base import FrameSource
from companion.sources.folder import IMAGE_SUFFIXES, FolderSource, list_images
from companion.sources.stream import StreamSource, parse_udp
from companion.sources.synthetic import SyntheticSource, parse_synthetic_uri
from companion.sources.v4l2 import V4L2Source
from companion.sources.video import VideoSource


def check_source_uri(uri: str) -> None:
    """A malformed synthetic:// or udp:// URI is a usage error before anything starts; the live companion
    would otherwise retry it forever, as if it were a camera that is not plugged in yet."""
    if uri.startswith("synthetic://"):
        parse_synthetic_uri(uri)
    elif uri.startswith("udp://"):
        parse_udp(uri)


def open_source(cfg: SourceConfig, *, realtime: bool | None = None) -> FrameSource:
    """The source for ``cfg.uri``; ``realtime`` overrides ``cfg.realtime`` (offline tools read files flat out)."""
    uri = cfg.uri
    paced = cfg.realtime if realtime is None else realtime
    if uri.startswith("synthetic://"):
        return SyntheticSource(uri, fps=cfg.fps, realtime=paced, width=cfg.width, height=cfg.height)
    if uri.startswith(("rtsp://", "rtsps://", "udp://")):
        return StreamSource(cfg)
    if uri.startswith(("/dev/video", "/dev/v4l/", "v4l2://")):
        return V4L2Source(cfg)
    if uri.startswith("file://"):
        uri = uri[len("file://"):]
    path = Path(uri).expanduser()
    if path.is_dir():
        return FolderSource(path, fps=cfg.fps, realtime=paced, loop=cfg.loop)
    if path.is_file():
        return VideoSource(path, fps=cfg.fps, realtime=paced, loop=cfg.loop)
    raise UsageError(f"source {cfg.uri}: no such file or folder")


LIVE_PREFIXES = ("/dev/video", "/dev/v4l/", "v4l2://", "rtsp://", "rtsps://", "udp://")
"""Cameras and streams: they can come back, so the live companion keeps retrying them."""


def file_source_path(uri: str) -> Path | None:
    """The file or folder a source URI names, or None for a camera, a stream or the generated dive."""
    if uri.startswith(("synthetic://", *LIVE_PREFIXES)):
        return None
    return Path(uri[len("file://"):] if uri.startswith("file://") else uri).expanduser()


def check_file_source(cfg: SourceConfig, option: str = "source") -> None:
    """A file or folder source that cannot be read now never will be (a camera can come back; a file cannot): one
    usage error naming the path and why, before anything starts, instead of retrying it for the whole run.
    ``option`` is how the user gave it (``--source``, or the config's ``source``)."""
    path = file_source_path(cfg.uri)
    if path is None:
        return
    if not path.exists():
        raise UsageError(f"{option} {cfg.uri}: no such file or folder")
    if path.is_dir():
        _check_folder(path, option)
        return
    try:
        source = VideoSource(path, fps=cfg.fps, realtime=False)
        try:
            first = next(iter(source), None)
        finally:
            source.close()
    except MerlionError as err:
        raise UsageError(f"{option} {cfg.uri}: {str(err).removeprefix(f'{path}: ')}") from None
    if first is None:
        raise UsageError(f"{option} {cfg.uri}: no frame could be decoded (corrupt or truncated video)")


def _check_folder(path: Path, option: str) -> None:
    try:
        images = list_images(path)
    except OSError as err:
        raise UsageError(f"{option} {path}: cannot be read ({err.strerror or err})") from None
    if not images:
        nested = []
        try:
            for sub in sorted(p for p in path.iterdir() if p.is_dir()):
                try:
                    count = len(list_images(sub))
                except OSError:
                    continue
                if count:
                    nested.append(f"{sub} has {count}")
        except OSError:
            pass
        where = f" ({', '.join(nested[:3])})" if nested else f" ({', '.join(sorted(IMAGE_SUFFIXES))})"
        raise UsageError(f"{option} {path}: no images in {path}{where}")
    try:
        next(iter(FolderSource(path, realtime=False)), None)
    except MerlionError:
        raise UsageError(f"{option} {path}: none of its {len(images)} images can be read") from None
