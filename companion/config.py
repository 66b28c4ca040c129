"""The one typed configuration object, built from YAML once at start-up and passed down.

No other module reads configuration files or environment variables. Every key has a default here, so an empty
file (or none at all) is a complete configuration that runs anywhere; ``config/default.yaml`` spells the same
defaults out with a comment per key, and a test keeps the two in step.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

import yaml
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError, field_validator

from vehicle.settings import MavlinkConfig, SurfaceConfig, TelemetryConfig

ENV_PREFIX = "MERLION__"


class ConfigError(Exception):
    """A configuration problem, worded as one line that names the file, the key and what is wrong."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class SourceConfig(_Section):
    uri: str = "synthetic://dive"
    """A video file, a folder of images, a V4L2 device (/dev/video0), rtsp://..., udp://@:5600 (RTP/H.264),
    or synthetic://dive (generated murky footage, so the defaults run anywhere)."""
    fps: float = Field(5.0, gt=0, le=240)
    """Frames per second kept after subsampling (the vehicle runs at 5)."""
    width: int | None = Field(None, gt=0)
    """Capture width asked of a live camera (None: the device default)."""
    height: int | None = Field(None, gt=0)
    fourcc: Literal["MJPG", "H264", "YUYV"] | None = None
    """Pixel format asked of a V4L2 device."""
    realtime: bool = True
    """Play files and folders at their own frame rate (as a camera would deliver them)."""
    loop: bool = False
    """Start a file or folder again when it ends."""
    retry_initial_s: float = Field(1.0, gt=0)
    retry_max_s: float = Field(30.0, gt=0)


Precision = Literal["auto", "fp32", "fp16-weights", "bf16", "fp16", "int8"]
"""Encoder precisions (``typing.get_args`` gives the command-line choices)."""


class EncoderConfig(_Section):
    name: Literal["auto", "clip", "imagenet", "visual"] = "auto"
    """auto: CLIP when its weights are available offline, else the packaged ImageNet encoder (said loudly)."""
    model: str = "ViT-B-32"
    """open_clip architecture name."""
    pretrained: str | None = "laion2b_s34b_b79k"
    """open_clip pretrained tag, used only when it is already in the local cache."""
    weights: str | None = None
    """A local CLIP checkpoint file; wins over `pretrained`."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    precision: Precision = "auto"
    """auto: fp16 on CUDA, bf16 on CPUs with native bf16 units, fp16-weights elsewhere (fp32 arithmetic on weights
    stored in fp16: half the tower's memory at about fp32's speed); int8 (CLIP, CPU only, never auto)."""
    runtime: Literal["torch", "onnx"] = "torch"
    """onnx: CLIP's image tower exported once and run by ONNX Runtime in fp32, with no torch in the process (see
    docs/encoders.md)."""
    providers: list[str] = Field(default_factory=list)
    """runtime onnx: ONNX Runtime execution providers, most preferred first (on a Jetson Orin
    [TensorrtExecutionProvider, CUDAExecutionProvider, CPUExecutionProvider]); empty: the CPU one."""
    batch: int = Field(8, ge=1, le=256)
    """Largest batch taken from the queue at once; smaller batches go as soon as they are there."""
    input_size: int | None = Field(None, gt=0)
    """Frames are downscaled to this side before encoding (None: what the model wants)."""
    cache_dir: str | None = None
    """Where CLIP's exported ONNX image towers and query embeddings are kept between starts, so a later start
    needs no torch for them (None: the service's CacheDirectory, /var/cache/merlion under the shipped unit, else
    $XDG_CACHE_HOME/merlion or ~/.cache/merlion). Unwritable: queries still work, later starts encode them again."""


QueryText = Annotated[str, StringConstraints(min_length=1, max_length=300)]
"""One query as typed: not empty, and short enough for a STATUSTEXT-sized explanation and the surface's file."""

TOPIC_NAME = r"^[a-z0-9][a-z0-9_-]{0,23}$"
"""A topic's name: it is in file names, FTP paths and 50-character STATUSTEXT lines, so short and plain."""


class TopicConfig(_Section):
    name: str = Field(pattern=TOPIC_NAME)
    """Short name (lower-case letters, digits, - and _; at most 24), carried by every capture of the topic."""
    positive: QueryText
    negatives: list[QueryText] = Field(default_factory=list)
    """With none, a generic negative ("an underwater image"), as for --query alone."""
    tau_ss: float | None = None
    """This topic's threshold; None: queries.tau_ss."""

    @field_validator("tau_ss")
    @classmethod
    def _fraction(cls, value: float | None) -> float | None:
        return None if value is None else as_fraction(value, allow_zero=True)


class QueryConfig(_Section):
    name: str = Field("main", pattern=TOPIC_NAME)
    """The name of the one topic that positive/negatives define (captures and the gallery carry it)."""
    positive: QueryText = "underwater image with fish"
    negatives: list[QueryText] = Field(default_factory=lambda: ["underwater image without fish"])
    tau_ss: float = 0.5
    """Semantic pre-sampling threshold, a fraction in [0, 1); a value above 1 is read as a percentage; 0 means no
    semantic gate (every frame goes on to the sampler)."""
    below_threshold_after_s: float = Field(60.0, ge=0)
    """When a topic's summary is empty and nothing has passed tau_ss for this many seconds of footage, its best frames so far are shown, marked below threshold, and the surface is told; the first frame that passes displaces them. 0: at once."""
    topics: list[TopicConfig] = Field(default_factory=list, max_length=8)
    """Several named topics followed at once, each with its own summary of K frames, e.g. [{name: fish, positive:
    ..., negatives: [...]}, {name: coral, ...}]; one encoder pass serves them all. Empty: the one topic above;
    given: these topics replace it (name/positive/negatives above are then not used). A topic may set its own
    tau_ss. A queries file uploaded from the surface replaces the topics, also across restarts (the store's
    queries.json), until these configured topics are changed (see docs/live-companion.md)."""

    @field_validator("tau_ss")
    @classmethod
    def _fraction(cls, value: float) -> float:
        return as_fraction(value, allow_zero=True)

    @field_validator("topics")
    @classmethod
    def _unique(cls, value: list[TopicConfig]) -> list[TopicConfig]:
        names = [t.name for t in value]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"topic name {twice[0]!r} is used twice")
        return value

    def topic_list(self) -> list[TopicConfig]:
        """The topics to follow, first one first (the single default topic when none are listed)."""
        if self.topics:
            return list(self.topics)
        return [TopicConfig(name=self.name, positive=self.positive, negatives=list(self.negatives))]


class SamplerConfig(_Section):
    k: int = Field(6, ge=1, le=1000)
    distance: Literal["js", "kl", "cosine"] = "js"
    threshold: Literal["mean", "min", "2min", "median"] = "mean"


class EnhanceConfig(_Section):
    mode: Literal["none", "always", "selective"] = "none"
    method: Literal["classic", "model"] = "classic"
    tau_ses: float = 0.7
    """Second threshold: an enhanced frame goes on only if its score passes this."""
    model_path: str | None = None
    """TorchScript (.pt) or ONNX (.onnx) image-to-image model, for method: model."""
    model_input_size: tuple[int, int] | None = None
    """(width, height) the model wants; None: any size divisible by 8."""
    model_value_range: Literal["0-1", "-1-1", "0-255"] = "0-1"
    queue: int = Field(4, ge=1)
    """Candidates waiting for the enhancer; more are dropped and counted."""

    @field_validator("tau_ses")
    @classmethod
    def _fraction(cls, value: float) -> float:
        return as_fraction(value)


class GateConfig(_Section):
    mode: Literal["none", "difference"] = "difference"
    """difference: a frame is encoded only when its tiny grey copy differs from the last encoded one (see
    docs/vision.md, the frame gate); none: every frame is encoded."""
    threshold: float = Field(8.0, ge=0, le=255)
    """Mean absolute difference in grey levels (0-255) on 32x18 copies above which a frame is encoded."""
    max_gap_s: float = Field(0.5, gt=0)
    """A frame this many seconds (source time) after the last encoded one is encoded whatever it shows (0.5: the
    gated summary then keeps the ungated one's segments, `merlion bench gate`)."""
    max_gap_share: float = Field(0.05, ge=0, lt=1)
    """A frame is also encoded once this share of the frames seen so far has passed since the last encoded one:
    every twentieth of the footage so far holds an encoded frame however short it is (a 1-s clip, the first round of
    a loop), while on long footage ``max_gap_s`` fires first. 0: off (time and difference only)."""


class StoreConfig(_Section):
    dir: str = "merlion-store"
    disk_budget_mb: float = Field(2048.0, gt=0)
    keep_raw: bool = True
    """Keep the raw frame beside the enhanced one."""


class HealthConfig(_Section):
    stall_after_s: float = Field(10.0, gt=0)
    """A stage that has not made progress for this long is stuck: no watchdog ping is sent."""


class LogConfig(_Section):
    level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"


def web_origin(text: str) -> str:
    """``scheme://host[:port]`` as browsers send it in ``Origin`` (lower case, no default port; an app's own scheme
    such as ``app://cockpit`` too); ValueError for anything else, and for ``null`` (what every sandboxed frame and
    ``file://`` page sends) and ``*``, which would let any page in."""
    raw = str(text).strip()
    try:
        parts = urlsplit(raw)
        port = parts.port
    except ValueError:
        parts, port = None, None
    if (parts is None or not parts.scheme or not parts.hostname or parts.path not in ("", "/") or parts.query
            or parts.fragment or parts.username or parts.password):
        raise ValueError(f"{raw!r} is not a web origin (expected SCHEME://HOST[:PORT], e.g. http://192.168.2.1:8080)")
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname
    default = {"http": 80, "https": 443}.get(parts.scheme)
    return f"{parts.scheme}://{host}" + (f":{port}" if port is not None and port != default else "")


class ExtensionConfig(_Section):
    allowed_origins: list[str] = Field(default_factory=list)
    """Web origins (SCHEME://HOST[:PORT]) whose pages may call the extension's HTTP actions and read its JSON, e.g.
    Cockpit served over HTTP from the topside computer (not its desktop app: ``file://`` is no such origin); empty
    (the default): same-origin requests only."""

    @field_validator("allowed_origins")
    @classmethod
    def _origins(cls, value: list[str]) -> list[str]:
        return [web_origin(v) for v in value]


class Config(_Section):
    source: SourceConfig = Field(default_factory=SourceConfig)
    encoder: EncoderConfig = Field(default_factory=EncoderConfig)
    queries: QueryConfig = Field(default_factory=QueryConfig)
    sampler: SamplerConfig = Field(default_factory=SamplerConfig)
    enhance: EnhanceConfig = Field(default_factory=EnhanceConfig)
    gate: GateConfig = Field(default_factory=GateConfig)
    mavlink: MavlinkConfig = Field(default_factory=MavlinkConfig)
    telemetry: TelemetryConfig = Field(default_factory=TelemetryConfig)
    surface: SurfaceConfig = Field(default_factory=SurfaceConfig)
    store: StoreConfig = Field(default_factory=StoreConfig)
    health: HealthConfig = Field(default_factory=HealthConfig)
    log: LogConfig = Field(default_factory=LogConfig)
    extension: ExtensionConfig = Field(default_factory=ExtensionConfig)


def as_fraction(value: float, *, allow_zero: bool = False) -> float:
    """Thresholds are fractions in (0, 1); operators often write percentages, so 40 means 0.4.

    ``allow_zero``: 0 is accepted too, for a gate where 0 means "no gate" (tau_ss).
    """
    given = value
    if value > 1.0:
        value = value / 100.0
    if allow_zero and value == 0.0:
        return 0.0
    if not 0.0 < value < 1.0:
        low = "[0" if allow_zero else "(0"
        raise ValueError(f"must be a fraction in {low}, 1) or a percentage in (1, 100), got {given}")
    return float(value)


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping: silently keeping the last of two
    ``sampler:`` sections would drop settings the user wrote."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"key {key!r} is given twice",
                                                        key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _describe(err: ValidationError) -> str:
    first = err.errors()[0]
    key = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"]
    if first["type"] == "extra_forbidden":
        msg = "unknown key"
    value = first.get("input")
    shown = "" if first["type"] == "extra_forbidden" or isinstance(value, dict) else f" (got {value!r})"
    if shown and f"got {value}" in msg:  # the validator's own message already names the value
        shown = ""
    return f"{key}: {msg}{shown}"


def _error_key(err: ValidationError) -> tuple[str, ...]:
    return tuple(str(p) for p in err.errors()[0]["loc"])


def given_in(over: dict[str, Any], key: tuple[str, ...]) -> bool:
    """Whether ``key`` (a dotted path) was set by these overrides."""
    node: Any = over
    for part in key:
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):  # an item of a list option
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return False
    return True


def env_overrides(environ: dict[str, str]) -> dict[str, Any]:
    """MERLION__SECTION__KEY=value, the value parsed as YAML (so numbers and lists work)."""
    tree: dict[str, Any] = {}
    for name, raw in sorted(environ.items()):
        if not name.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in name[len(ENV_PREFIX) :].split("__") if p]
        if not path:
            continue
        node = tree
        for part in path[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"environment {name}: conflicts with another override")
        node[path[-1]] = yaml.safe_load(raw) if raw != "" else None
    return tree


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def build_config(data: dict[str, Any] | None = None, *, origin: str = "config") -> Config:
    """Validate a plain mapping; errors name the origin and the dotted key."""
    try:
        return Config.model_validate(data or {})
    except ValidationError as err:
        raise ConfigError(f"{origin}: {_describe(err)}") from None


def load_config(
    path: str | os.PathLike[str] | None = None,
    *,
    overrides: dict[str, Any] | None = None,
    environ: dict[str, str] | None = None,
    options: dict[str, str] | None = None,
) -> Config:
    """The file (if any), then MERLION__* environment variables, then command-line overrides (nested dicts).

    ``options`` names the command-line option of a dotted key (``{"sampler.k": "-k"}``): a bad value given on the
    command line is blamed on that option (else on "command line"), not on the file or the defaults.
    """
    data: dict[str, Any] = {}
    origin = "defaults"
    if path is not None:
        p = Path(path)
        origin = str(p)
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such config file") from None
        except OSError as err:
            raise ConfigError(f"{p}: cannot read ({err.strerror})") from None
        except UnicodeDecodeError as err:
            raise ConfigError(f"{p}: not a UTF-8 text file (byte {err.start}); is this the YAML config?") from None
        try:
            loaded = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
        except yaml.YAMLError as err:
            mark = getattr(err, "problem_mark", None)
            where = f" line {mark.line + 1}" if mark is not None else ""
            problem = getattr(err, "problem", None) or "not valid YAML"
            raise ConfigError(f"{p}:{where}: {problem}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{p}: top level must be a mapping of sections, got {type(loaded).__name__}")
        data = loaded
    env = env_overrides(dict(os.environ) if environ is None else environ)
    if env:
        data = _merge(data, env)
        origin = f"{origin} (with {ENV_PREFIX}* environment overrides)"
    if overrides:
        data = _merge(data, overrides)
    try:
        return Config.model_validate(data or {})
    except ValidationError as err:
        key = _error_key(err)
        if overrides and given_in(overrides, key):  # the command line's value: blame its option, not the file
            option = (options or {}).get(".".join(p for p in key if not p.isdigit()))
            raise ConfigError(f"{option or 'command line'}: {_describe(err)}") from None
        raise ConfigError(f"{origin}: {_describe(err)}") from None
