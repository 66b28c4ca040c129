"""A contact sheet: the summary frames in a grid, each labelled with its time (a still: its file name) and score,
for a glance at a dive."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

BACKGROUND = (32, 32, 32)
TEXT = (240, 240, 240)


@dataclass(frozen=True)
class Tile:
    image: np.ndarray
    """BGR uint8, any size."""
    time_s: float
    score: float
    depth_m: float | None = None
    """Drawn when known (the live companion's frames carry a pose)."""
    label: str | None = None
    """Drawn instead of the time when given: a still's file name (stills have no clock of their own)."""


def format_time(seconds: float) -> str:
    """12.3 -> '0:12.3', 3725 -> '1:02:05.0' (a dive is minutes to hours long)."""
    minutes, sec = divmod(max(0.0, seconds), 60.0)
    hours, minutes = divmod(int(minutes), 60)
    return f"{hours}:{minutes:02d}:{sec:04.1f}" if hours else f"{minutes}:{sec:04.1f}"


def fit_text(name: str, tail: str, width: int, font: int, scale: float, thick: int) -> str:
    """``name + tail`` shortened in the middle of ``name`` (``7117_Car...f000006.jpg``) until it fits ``width``."""
    text, keep = name + tail, len(name)
    while keep > 4 and cv2.getTextSize(text, font, scale, thick)[0][0] > width:
        keep -= 1
        text = f"{name[:keep // 2]}...{name[len(name) - (keep - keep // 2):]}{tail}"
    return text


def contact_sheet(tiles: Sequence[Tile], *, tile_width: int = 320, columns: int | None = None,
                  title: str = "") -> np.ndarray:
    """One BGR image with every tile scaled to ``tile_width`` and a label band under it.

    With no tiles it still returns a small sheet saying so, so the output directory is always complete.
    """
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1
    band = 24
    head = 30 if title else 0
    if not tiles:
        sheet = np.full((80 + head, 2 * tile_width, 3), BACKGROUND, np.uint8)
        cv2.putText(sheet, "no frame passed the query", (10, head + 45), font, 0.6, TEXT, thick, cv2.LINE_AA)
        if title:
            cv2.putText(sheet, title, (10, 20), font, scale, TEXT, thick, cv2.LINE_AA)
        return sheet
    cols = columns or min(len(tiles), max(1, math.ceil(math.sqrt(len(tiles)))))
    rows = math.ceil(len(tiles) / cols)
    heights = [round(t.image.shape[0] * tile_width / t.image.shape[1]) for t in tiles]
    cell_h = max(heights) + band
    pad = 4
    sheet = np.full((head + rows * (cell_h + pad) + pad, cols * (tile_width + pad) + pad, 3), BACKGROUND, np.uint8)
    if title:
        cv2.putText(sheet, title, (pad + 4, 20), font, scale, TEXT, thick, cv2.LINE_AA)
    for i, (tile, h) in enumerate(zip(tiles, heights, strict=True)):
        r, c = divmod(i, cols)
        x, y = pad + c * (tile_width + pad), head + pad + r * (cell_h + pad)
        interp = cv2.INTER_AREA if tile.image.shape[1] > tile_width else cv2.INTER_LINEAR
        sheet[y:y + h, x:x + tile_width] = cv2.resize(tile.image, (tile_width, h), interpolation=interp)
        tail = f"   score {tile.score:.2f}"
        if tile.depth_m is not None and math.isfinite(tile.depth_m):
            tail += f"   {tile.depth_m:.1f} m"
        if tile.label is None:
            label = f"t {format_time(tile.time_s)}{tail}"
        else:
            label = fit_text(tile.label, tail, tile_width - 8, font, scale, thick)
        cv2.putText(sheet, label, (x + 4, y + h + 17), font, scale, TEXT, thick, cv2.LINE_AA)
    return sheet
