"""A summary frame's files in the store: ``frames/<n>.jpg`` (and ``.raw.jpg``), ``.npy`` and the ``.json``
sidecar, written one by one atomically with the sidecar last (so a sidecar marks a complete frame), and read back."""

from __future__ import annotations

import io
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.atomic_write import atomic_write
from companion.vision.events import SummaryFrame
from vehicle.autopilot.pose import Pose

FORMAT_VERSION = 1


def read_no_link(path: Path) -> bytes | None:
    """``path``'s bytes; None when it is missing, unreadable or a symbolic link (``O_NOFOLLOW``): what the store
    serves over the link is its own file, never one a link in ``frames/`` points at (/etc/shadow)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as fh:
        return fh.read()


def frame_name(index: int) -> str:
    return f"{index:06d}"


def _encode_jpeg(image: np.ndarray, quality: int = 95) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("could not encode the frame as JPEG")
    return buf.tobytes()


def _npy_bytes(array: np.ndarray) -> bytes:
    bio = io.BytesIO()
    np.save(bio, np.asarray(array, dtype=np.float32), allow_pickle=False)
    return bio.getvalue()


def pose_from_dict(data: dict[str, Any] | None) -> Pose | None:
    if not data:
        return None
    data = dict(data)
    if data.get("q") is not None:
        data["q"] = tuple(data["q"])
    known = set(Pose.__dataclass_fields__)
    return Pose(**{k: v for k, v in data.items() if k in known})


def sidecar_for(frame: SummaryFrame, *, tags: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON sidecar of a summary frame: what a person or the surface needs to know about it."""
    h, w = frame.image.shape[:2]
    return {
        "version": FORMAT_VERSION,
        "image_index": frame.image_index,
        "frame_index": frame.frame_index,
        "time_s": frame.time_s,
        "capture_time": frame.capture_time,
        "capture_utc": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(frame.capture_time))
        + f".{int((frame.capture_time % 1) * 1000):03d}Z",
        "score": float(frame.score),
        "raw_score": None if frame.raw_score is None else float(frame.raw_score),
        "enhanced": bool(frame.enhanced),
        "width": int(w),
        "height": int(h),
        "file": f"frames/{frame_name(frame.image_index)}.jpg",
        "raw_file": None,
        "feature_file": f"frames/{frame_name(frame.image_index)}.npy",
        "pose": frame.pose.to_dict() if frame.pose is not None else None,
        "topic": frame.topic,
        "below_threshold": bool(frame.below_threshold),
        "pilot": bool(frame.pilot),
        "tags": dict(tags or {}),
    }


@dataclass
class HeldFrame:
    """A summary frame the store holds (in memory too, so a memory-only store can still answer)."""

    frame: SummaryFrame
    sidecar: dict[str, Any]
    on_disk: bool = False


class DamagedFrame(ValueError):
    """A frame's files are missing or damaged; the message names the file and what is wrong with it."""


def read_frame(store_dir: Path, index: int) -> HeldFrame | None:
    """A complete frame from disk (its sidecar, written last, marks it complete); None when absent or damaged."""
    try:
        return load_frame(store_dir, index)
    except DamagedFrame:
        return None


def load_frame(store_dir: Path, index: int) -> HeldFrame:
    """A complete frame from disk, or DamagedFrame saying which of its files is missing or damaged."""
    base = store_dir / "frames" / frame_name(index)
    sidecar = _read_part(base.with_suffix(".json"), lambda p: json.loads(p.read_text(encoding="utf-8")))
    feature = _read_part(base.with_suffix(".npy"), _load_npy)
    image = _read_part(base.with_suffix(".jpg"), lambda p: cv2.imread(str(p), cv2.IMREAD_COLOR))
    if image is None:
        raise DamagedFrame(f"{base.with_suffix('.jpg').name}: missing or not an image")
    if not isinstance(sidecar, dict):
        raise DamagedFrame(f"{base.with_suffix('.json').name}: not a JSON object")
    why = feature_problem(feature)
    if why:
        raise DamagedFrame(f"{base.with_suffix('.npy').name}: {why}")
    try:
        held = _held_from(store_dir, sidecar, image, feature.astype(np.float32))
    except (KeyError, TypeError, ValueError) as err:  # a sidecar edited by hand or damaged: that frame is dropped
        raise DamagedFrame(f"{base.with_suffix('.json').name}: {type(err).__name__} {err}") from None
    if held.frame.image_index != index:  # resumed under its file's index, it would be announced twice
        raise DamagedFrame(f"{base.with_suffix('.json').name}: names image {held.frame.image_index}")
    return held


def _read_part(path: Path, read: Callable[[Path], Any]) -> Any:
    try:
        return read(path)
    except FileNotFoundError:
        raise DamagedFrame(f"{path.name}: missing") from None
    except (OSError, ValueError, EOFError) as err:  # EOFError: an empty or cut .npy
        raise DamagedFrame(f"{path.name}: {err}") from None


def _load_npy(path: Path) -> np.ndarray:
    value = np.load(path, allow_pickle=False)
    if not isinstance(value, np.ndarray):  # a file that starts like a zip: np.load opens it as an .npz archive
        value.close()
        raise ValueError("an .npz archive, not an array")
    return value


def feature_problem(feature: np.ndarray) -> str:
    """Why ``feature`` cannot be a stored sampler feature ("" when it can): one finite real vector."""
    if feature.ndim != 1 or feature.size == 0:
        return f"shape {feature.shape}, not a vector"
    if not (np.issubdtype(feature.dtype, np.floating) or np.issubdtype(feature.dtype, np.integer)):
        return f"{feature.dtype} values, not numbers"
    if not np.isfinite(feature).all():
        return "values that are not finite"
    return ""


def _held_from(store_dir: Path, sidecar: dict[str, Any], image: np.ndarray, feature: np.ndarray) -> HeldFrame:
    raw = None
    if sidecar.get("raw_file"):
        raw = cv2.imread(str(store_dir / sidecar["raw_file"]), cv2.IMREAD_COLOR)
    frame = SummaryFrame(
        image_index=int(sidecar["image_index"]),
        frame_index=int(sidecar.get("frame_index", 0)),
        time_s=float(sidecar.get("time_s", 0.0)),
        capture_time=float(sidecar.get("capture_time", 0.0)),
        score=float(sidecar.get("score", 0.0)),
        image=image,
        feature=feature,
        pose=pose_from_dict(sidecar.get("pose")),
        raw_image=raw,
        enhanced=bool(sidecar.get("enhanced", False)),
        topic=str(sidecar.get("topic") or ""),
        below_threshold=bool(sidecar.get("below_threshold", False)),
        pilot=bool(sidecar.get("pilot", False)),
        raw_score=None if sidecar.get("raw_score") is None else float(sidecar["raw_score"]),
    )
    return HeldFrame(frame=frame, sidecar=sidecar, on_disk=True)


def write_frame_files(store_dir: Path, held: HeldFrame, *, keep_raw: bool) -> None:
    """The frame's JPEG (and raw JPEG), feature and sidecar, each atomically, the sidecar last."""
    frames_dir = store_dir / "frames"
    frame = held.frame
    base = frames_dir / frame_name(frame.image_index)
    atomic_write(base.with_suffix(".jpg"), _encode_jpeg(frame.image))
    if frame.enhanced and frame.raw_image is not None and keep_raw:
        raw_path = frames_dir / f"{frame_name(frame.image_index)}.raw.jpg"
        atomic_write(raw_path, _encode_jpeg(frame.raw_image))
        held.sidecar["raw_file"] = f"frames/{raw_path.name}"
    write_feature_files(store_dir, held)


def write_feature_files(store_dir: Path, held: HeldFrame) -> None:
    """The frame's feature, then its sidecar (which names the encoder that made the feature), each atomically."""
    base = store_dir / "frames" / frame_name(held.frame.image_index)
    atomic_write(base.with_suffix(".npy"), _npy_bytes(held.frame.feature))
    atomic_write(base.with_suffix(".json"), json.dumps(held.sidecar, indent=1).encode())


def encoder_of(sidecar: dict[str, Any]) -> str:
    """The encoder a stored frame's feature was made with ("" when its sidecar does not say)."""
    tags = sidecar.get("tags")
    name = tags.get("encoder") if isinstance(tags, dict) else None
    return name if isinstance(name, str) else ""
