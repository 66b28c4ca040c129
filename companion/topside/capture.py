"""What the gallery knows of a frame (``Capture``) and of a topic the companion follows (``Topic``), and which dive
ids may name a folder in DIR (``safe_dive``)."""

from __future__ import annotations

import re
from dataclasses import dataclass, fields, replace

_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")


def safe_dive(dive: str) -> str:
    """``dive`` when it may name a folder in DIR, else ValueError. A dive id comes from the wire (a capture's
    ``file_url``, index.json) and becomes ``dives/<dive>/`` and ``full/<dive>/``: ``..`` or ``/tmp/x`` there would
    move thumbnails, or write a full frame the page asked for, outside DIR. The companion makes 8 hex digits."""
    if not isinstance(dive, str) or not _SAFE_NAME.fullmatch(dive):
        raise ValueError(f"dive id {str(dive)[:80]!r} is not a safe name (letters, digits, _ and -, at most 64)")
    return dive


@dataclass(frozen=True)
class Topic:
    """A topic the companion follows, as its index.json states it: the page heads the topic's frames with it."""

    name: str
    positive: str
    negatives: tuple[str, ...] = ()

    @classmethod
    def from_dict(cls, data: dict) -> Topic:
        return cls(str(data["name"]), str(data.get("positive") or ""), tuple(str(n) for n in data.get("negatives") or ()))

    def to_dict(self) -> dict:
        return {"name": self.name, "positive": self.positive, "negatives": list(self.negatives)}


@dataclass
class Capture:
    """One summary frame as the surface knows it; fields the companion has not told us yet are None."""

    image_index: int
    dive: str | None = None
    """The vehicle store's dive id; None from a companion that sends none."""
    time_utc: float | None = None
    """Seconds since epoch at capture (companion clock)."""
    depth_m: float | None = None
    """Metres below the surface (positive down)."""
    heading_deg: float | None = None
    q: list[float] | None = None
    """Attitude quaternion w-x-y-z."""
    lat: float | None = None
    lon: float | None = None
    alt_m: float | None = None
    score: float | None = None
    raw_score: float | None = None
    """The frame's score as captured when ``score`` is its enhanced copy's (index.json); else None."""
    topic: str | None = None
    """The name of the topic whose summary holds it (index.json, or the STATUSTEXT when several are followed);
    None until the companion said (and in a gallery written before topics)."""
    below_threshold: bool | None = None
    """A stand-in (index.json): nothing passed the threshold for a while, so the best frame seen is shown."""
    file_url: str | None = None
    thumbnail: str | None = None
    """Path of the thumbnail relative to DIR, once we have it."""
    thumbnail_via: str | None = None
    """push | ftp."""
    thumbnail_bytes: int | None = None
    thumbnail_crc32: int | None = None
    """CRC-32 (MAVLink FTP flavour) of the companion's thumbnail file, from index.json."""
    in_summary: bool = True
    announced_at: float | None = None
    """Surface wall clock when we first heard of it."""
    removed_at: float | None = None

    @classmethod
    def from_dict(cls, data: dict) -> Capture:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    def to_dict(self) -> dict:
        """Its fields, shallow (``asdict`` deep-copies: 0.22 s for the 12,288 captures a gallery may hold, on the
        receive loop at each gallery.json rewrite); ``q`` is shared, so only for writing out."""
        return {name: getattr(self, name) for name in CAPTURE_FIELDS}

    def copy(self) -> Capture:
        """A copy a reader may keep (its own ``q``)."""
        return replace(self, q=None if self.q is None else list(self.q))


CAPTURE_FIELDS = tuple(f.name for f in fields(Capture))
