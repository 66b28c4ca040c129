"""The frame-source interface that file, folder, camera and stream sources share."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator

from companion.sources.frame import Frame


class FrameSource(ABC):
    """An iterable of frames, already subsampled to the target rate.

    ``lost`` counts frames the source could not decode (corrupt or truncated input); ``dropped`` counts frames
    skipped on purpose (subsampling is not dropping). Sources are context managers and must release devices
    and files on ``close()``.
    """

    name: str = "source"
    lost: int = 0

    @abstractmethod
    def __iter__(self) -> Iterator[Frame]: ...

    def origin(self, index: int) -> str | None:
        """The file a frame came from, when the source is made of separate files (an image folder); else None."""
        return None

    def close(self) -> None:  # noqa: B027 - sources without a device need no close
        """Release the device or file; safe to call twice."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
