"""``synthetic://dive``: generated murky underwater footage, so the defaults and the demo run on any machine.

The project may not ship real dive video, so the default source draws one: a descent through blue water with
marine snow, a bare sandy floor, a reef with a school of striped reef fish, sea grass, and a few large orange
fish, each segment a few seconds long, all under a green-blue cast, haze and sensor noise. It is procedural and
deterministic (the same seed gives the same frames), so tests can rely on it. The fish segments are what the
default query ("underwater image with fish") should find; the others are what it should leave out.

Options ride on the URI: ``synthetic://dive?seconds=8&width=640&height=360&seed=1`` (seconds per segment).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from urllib.parse import parse_qs, urlparse

import cv2
import numpy as np

from companion.errors import UsageError
from companion.sources.base import FrameSource
from companion.sources.frame import Frame

SEGMENTS = ("descent", "sand", "reef_fish", "seagrass", "big_fish")
"""In dive order; the footage repeats them (with fresh random detail) for as long as it runs."""
FISH_SEGMENTS = frozenset({"reef_fish", "big_fish"})


@dataclass(frozen=True)
class SyntheticOptions:
    seconds: float = 8.0
    width: int = 640
    height: int = 360
    seed: int = 1
    segments: int = 0
    """Stop after this many segments (0: run until closed)."""


def parse_synthetic_uri(uri: str) -> SyntheticOptions:
    parsed = urlparse(uri)
    if parsed.scheme != "synthetic" or parsed.netloc not in ("dive", ""):
        raise UsageError(f"source {uri!r}: the synthetic source is synthetic://dive")
    query = {k: v[-1] for k, v in parse_qs(parsed.query).items()}
    known = set(SyntheticOptions.__dataclass_fields__)
    unknown = sorted(set(query) - known)
    if unknown:
        raise UsageError(f"source {uri!r}: unknown option {unknown[0]!r} (known: {', '.join(sorted(known))})")
    try:
        opts = SyntheticOptions(
            seconds=float(query.get("seconds", 8.0)), width=int(query.get("width", 640)),
            height=int(query.get("height", 360)), seed=int(query.get("seed", 1)),
            segments=int(query.get("segments", 0)),
        )
    except ValueError as err:
        raise UsageError(f"source {uri!r}: {err}") from None
    if opts.seconds <= 0 or not (32 <= opts.width <= 4096) or not (32 <= opts.height <= 4096) or opts.segments < 0:
        raise UsageError(f"source {uri!r}: seconds > 0, width/height in 32..4096, segments >= 0")
    return opts


def segment_at(time_s: float, seconds: float) -> str:
    """Which scene the dive shows at ``time_s`` (tests and the demo report use it as ground truth)."""
    return SEGMENTS[int(time_s // seconds) % len(SEGMENTS)]


class _Scene:
    """One segment's static backdrop and moving cast, drawn at a given time."""

    def __init__(self, kind: str, w: int, h: int, rng: np.random.Generator) -> None:
        self.kind, self.w, self.h = kind, w, h
        self.pan = 2 * w
        self.backdrop = self._backdrop(rng)
        self.fish = self._cast(rng)
        self.snow = rng.random((160, 3)) * np.array([w, h, 1.0])

    def _backdrop(self, rng: np.random.Generator) -> np.ndarray:
        w, h = self.pan + self.w, self.h
        y = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None, None]
        water_top = np.array([150, 120, 40], np.float32)  # BGR: blue-green water
        water_deep = np.array([90, 70, 20], np.float32)
        img = np.broadcast_to(water_top * (1 - y) + water_deep * y, (h, w, 3)).copy()
        if self.kind == "descent":
            return img.astype(np.uint8)
        floor_y = int(h * (0.45 if self.kind != "reef_fish" else 0.55))
        noise = cv2.resize(rng.random((h // 8 + 1, w // 8 + 1)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
        sand = np.array([120, 160, 170], np.float32)
        ground = sand[None, None, :] * (0.75 + 0.35 * noise[..., None])
        img[floor_y:] = ground[floor_y:]
        if self.kind in ("sand", "big_fish"):
            # sand ripples (dark oval rocks were tried: the packaged encoder took them for fish)
            for _ in range(60):
                x0, y0 = int(rng.integers(0, w)), int(rng.integers(floor_y + 4, h))
                length = int(rng.integers(20, 80))
                cv2.line(img, (x0, y0), (x0 + length, y0 + int(rng.integers(-3, 4))), (105, 140, 150), 2)
        if self.kind == "reef_fish":
            for _ in range(40):  # coral heads and branches
                cx, cy = int(rng.integers(0, w)), int(rng.integers(floor_y - 30, h))
                colour = [(90, 90, 200), (160, 110, 200), (80, 160, 210), (120, 200, 140)][int(rng.integers(0, 4))]
                cv2.circle(img, (cx, cy), int(rng.integers(12, 40)), colour, -1)
                for _ in range(4):
                    ang = rng.uniform(-2.6, -0.5)
                    length = rng.uniform(20, 60)
                    tip = (int(cx + length * math.cos(ang)), int(cy + length * math.sin(ang)))
                    cv2.line(img, (cx, cy), tip, colour, int(rng.integers(3, 8)))
        if self.kind == "seagrass":
            for _ in range(220):
                x0, y0 = int(rng.integers(0, w)), int(rng.integers(floor_y, h))
                tall = rng.uniform(30, 110)
                lean = rng.uniform(-0.4, 0.4)
                tip = (int(x0 + tall * lean), int(y0 - tall))
                cv2.line(img, (x0, y0), tip, (60, 140 + int(rng.integers(0, 60)), 70), 2)
        return np.clip(img, 0, 255).astype(np.uint8)

    def _cast(self, rng: np.random.Generator) -> list[dict]:
        if self.kind == "reef_fish":
            return [dict(x=rng.uniform(0, self.w), y=rng.uniform(0.2, 0.7) * self.h, size=rng.uniform(38, 70),
                         speed=rng.uniform(25, 60) * rng.choice([-1, 1]), phase=rng.uniform(0, 6.3), striped=True,
                         colour=(20, 110, 245)) for _ in range(7)]
        if self.kind == "big_fish":
            return [dict(x=rng.uniform(0, self.w), y=rng.uniform(0.25, 0.6) * self.h, size=rng.uniform(90, 140),
                         speed=rng.uniform(15, 35) * rng.choice([-1, 1]), phase=rng.uniform(0, 6.3), striped=False,
                         colour=(30, 140, 235)) for _ in range(3)]
        return []

    def draw(self, t: float, progress: float) -> np.ndarray:
        x0 = int(progress * self.pan)
        img = self.backdrop[:, x0:x0 + self.w].copy()
        for f in self.fish:
            x = (f["x"] + f["speed"] * t) % (self.w + 2 * f["size"]) - f["size"]
            y = f["y"] + 0.1 * f["size"] * math.sin(t * 1.3 + f["phase"])
            _draw_fish(img, x, y, f["size"], 1 if f["speed"] > 0 else -1, f["colour"], f["striped"], t + f["phase"])
        for sx, sy, s in self.snow:  # marine snow drifting down
            py = int((sy + 12 * t * (0.5 + s)) % self.h)
            cv2.circle(img, (int(sx), py), 1 + int(s * 1.5), (200, 210, 210), -1)
        return img


def _draw_fish(img: np.ndarray, x: float, y: float, size: float, facing: int, colour: tuple[int, int, int],
               striped: bool, t: float) -> None:
    body = (int(size * 0.55), int(size * 0.28))
    cx, cy = int(x), int(y)
    wag = math.sin(t * 8) * 0.25
    tail_root = (cx - facing * body[0], cy)
    tail = np.array([tail_root,
                     (int(tail_root[0] - facing * size * 0.35), int(cy - size * (0.25 + wag * 0.3))),
                     (int(tail_root[0] - facing * size * 0.35), int(cy + size * (0.25 - wag * 0.3)))], np.int32)
    cv2.fillConvexPoly(img, tail, colour)
    cv2.ellipse(img, (cx, cy), body, 0, 0, 360, colour, -1)
    fin = np.array([(cx - facing * body[0] // 3, cy - body[1]), (cx + facing * body[0] // 3, cy - body[1]),
                    (cx - facing * body[0] // 4, int(cy - body[1] * 1.7))], np.int32)
    cv2.fillConvexPoly(img, fin, colour)
    if striped:
        for k in (-0.45, 0.05, 0.5):
            sx = int(cx + facing * k * body[0])
            cv2.ellipse(img, (sx, cy), (max(2, int(size * 0.06)), int(body[1] * 0.95)), 0, 0, 360, (245, 245, 245), -1)
            cv2.ellipse(img, (sx, cy), (max(2, int(size * 0.06)), int(body[1] * 0.95)), 0, 0, 360, (20, 20, 20), 1)
    else:
        cv2.ellipse(img, (cx, cy + body[1] // 3), (int(body[0] * 0.8), body[1] // 3), 0, 0, 360,
                    tuple(min(255, c + 40) for c in colour), -1)
    eye = (int(cx + facing * body[0] * 0.6), int(cy - body[1] * 0.25))
    cv2.circle(img, eye, max(2, int(size * 0.06)), (240, 240, 240), -1)
    cv2.circle(img, eye, max(1, int(size * 0.03)), (10, 10, 10), -1)


def murk(img: np.ndarray, rng: np.random.Generator, depth_factor: float) -> np.ndarray:
    """Turn a clean drawing into murky footage: haze toward the water colour, colour loss, blur, sensor noise."""
    water = np.array([120, 100, 35], np.float32)
    haze = 0.28 + 0.2 * depth_factor
    out = img.astype(np.float32) * (1 - haze) + water * haze
    out[..., 2] *= 0.8 - 0.25 * depth_factor  # red dies first underwater
    out = cv2.GaussianBlur(out, (0, 0), 1.2)
    out += rng.normal(0.0, 5.0, size=out.shape[:2])[..., None].astype(np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


class SyntheticSource(FrameSource):
    """A procedural dive at ``fps`` frames per second; realtime pacing like a camera, or as fast as asked."""

    def __init__(self, uri: str = "synthetic://dive", *, fps: float = 5.0, realtime: bool = True,
                 width: int | None = None, height: int | None = None) -> None:
        self.options = parse_synthetic_uri(uri)
        self.name = uri
        self.fps = float(fps)
        self.realtime = realtime
        self.width = width or self.options.width
        self.height = height or self.options.height
        self.lost = 0
        self._closed = False
        self._scenes: dict[int, _Scene] = {}

    def _scene(self, number: int) -> _Scene:
        scene = self._scenes.get(number)
        if scene is None:
            rng = np.random.default_rng([self.options.seed, number])
            scene = _Scene(SEGMENTS[number % len(SEGMENTS)], self.width, self.height, rng)
            self._scenes = {number: scene}  # one at a time keeps memory flat on a long run
        return scene

    def render(self, index: int) -> np.ndarray:
        """Frame ``index`` of the dive (deterministic)."""
        t = index / self.fps
        number = int(t // self.options.seconds)
        local = t - number * self.options.seconds
        scene = self._scene(number)
        img = scene.draw(local, local / self.options.seconds)
        depth_factor = 0.5 + 0.5 * math.sin(number * 0.9)
        return murk(img, np.random.default_rng([self.options.seed, index, 7]), depth_factor)

    def __iter__(self) -> Iterator[Frame]:
        start = time.monotonic()
        index = 0
        limit = self.options.segments * self.options.seconds
        while not self._closed:
            t = index / self.fps
            if limit and t >= limit:
                return
            if self.realtime:
                delay = start + t - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            image = self.render(index)
            yield Frame(image=image, index=index, time_s=t, capture_time=time.time())
            index += 1

    def close(self) -> None:
        self._closed = True
