"""Turn the configured source URI into a frame source: one readable dispatch, one branch per kind of source."""

from __future__ import annotations

from pathlib import Path

from companion.config import SourceConfig
from companion.errors import UsageError
from companion.sources.base import FrameSource
from companion.sources.folder import FolderSource
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
