"""On-board storage of the summary: survives crashes, reboots, full and read-only disks.

Layout of the store directory::

    frames/000042.jpg        the summary frame at full resolution (the enhanced one when enhancement ran)
    frames/000042.raw.jpg    the frame before enhancement (when enhanced and store.keep_raw)
    frames/000042.npy        the sampler feature, so a restart resumes with the same summary
    frames/000042.json       the sidecar: tags, pose, score, times; written last, so it marks a complete frame
    summary.json             the current summary (image indices), the next image index and the dive id
    changes.jsonl            append-only log of every change (one JSON object a line)

Every file is written atomically (temp file, fsync, rename, fsync of the directory), so a crash leaves either the
old file or the new one, never half of one. When the disk is full or read-only the store keeps going in memory
and says so once; the vehicle keeps working and what was saved before stays intact.
"""

from __future__ import annotations

import errno
import io
import json
import logging
import os
import secrets
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.atomic_write import TMP_PREFIX, atomic_write
from companion.config import StoreConfig
from companion.storage.versioned import upgrade
from companion.vision.events import SummaryEvent, SummaryFrame
from vehicle.autopilot.pose import Pose

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
CHANGES_FILE = "changes.jsonl"
FORMAT_VERSION = 1


def _name(index: int) -> str:
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
        "enhanced": bool(frame.enhanced),
        "width": int(w),
        "height": int(h),
        "file": f"frames/{_name(frame.image_index)}.jpg",
        "raw_file": None,
        "feature_file": f"frames/{_name(frame.image_index)}.npy",
        "pose": frame.pose.to_dict() if frame.pose is not None else None,
        "topic": frame.topic,
        "tags": dict(tags or {}),
    }


@dataclass
class StoreStats:
    frames_written: int = 0
    frames_pruned: int = 0
    write_errors: int = 0
    bytes_on_disk: int = 0


@dataclass
class _Held:
    """A summary frame the store holds (in memory too, so a memory-only store can still answer)."""

    frame: SummaryFrame
    sidecar: dict[str, Any]
    on_disk: bool = False


@dataclass
class ResumeState:
    """What a restart continues from."""

    frames: list[SummaryFrame] = field(default_factory=list)
    next_image_index: int = 0


class Store:
    """The summary on disk, kept in step with SummaryEvents; thread-safe."""

    def __init__(self, cfg: StoreConfig, *, directory: str | os.PathLike[str] | None = None) -> None:
        self.cfg = cfg
        self.dir = Path(directory if directory is not None else cfg.dir)
        self.frames_dir = self.dir / "frames"
        self.budget_bytes = int(cfg.disk_budget_mb * 1024 * 1024)
        self.stats = StoreStats()
        self.memory_only = False
        self.memory_only_reason = ""
        self._lock = threading.RLock()
        self._held: dict[int, _Held] = {}
        self._summary: list[int] = []
        self._next_index = 0
        self.dive = ""
        """This store's dive id: made when the store is created (or its summary file is gone), kept across
        restarts, so the surface can tell a new dive's image 0 from the last dive's."""
        self._open()

    # ---- start-up -------------------------------------------------------------------------------------------
    def _open(self) -> None:
        self._refuse_newer()
        try:
            self.frames_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            if not self.frames_dir.is_dir():
                self._degrade(err)
                return
        try:
            self._clean_temp_files()
            self._check_writable()
            self._end_torn_change()
        except OSError as err:
            self._degrade(err)  # a full or read-only disk: what is there is still resumed, in memory
        self._load()

    def _refuse_newer(self) -> None:
        """A store written by a newer merlion is neither read as ours nor touched: stop (NewerFileError)."""
        path = self.dir / SUMMARY_FILE
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return  # absent or damaged: _load rebuilds from the change log
        if isinstance(data, dict) and isinstance(data.get("version"), int) and data["version"] > FORMAT_VERSION:
            upgrade(path, data, current=FORMAT_VERSION, migrations={})

    def _end_torn_change(self) -> None:
        """A kill in the middle of a change-log line leaves it without its newline: cut it off, or the next run's
        first line would be glued to it and lost as well."""
        path = self.dir / CHANGES_FILE
        try:
            with open(path, "rb+") as fh:
                size = fh.seek(0, os.SEEK_END)
                start = max(0, size - 65536)  # a line is far shorter; the log itself may be long
                fh.seek(start)
                tail = fh.read()
                if tail and not tail.endswith(b"\n"):
                    cut = tail.rfind(b"\n")
                    fh.truncate(start + cut + 1 if cut >= 0 else start)
                    os.fsync(fh.fileno())
        except FileNotFoundError:
            return

    def _check_writable(self) -> None:
        probe = self.dir / f"{TMP_PREFIX}probe.{os.getpid()}"
        with open(probe, "wb") as fh:
            fh.write(b"ok")
        probe.unlink()

    def _clean_temp_files(self) -> None:
        """Half-written files of a crashed run are never read; remove them."""
        for directory in (self.dir, self.frames_dir):
            for path in directory.glob(f"{TMP_PREFIX}*"):
                try:
                    path.unlink()
                except OSError:
                    pass

    def _load(self) -> None:
        summary_path = self.dir / SUMMARY_FILE
        indices: list[int] = []
        next_index = 0
        dive = ""
        if summary_path.exists():
            try:
                data = json.loads(summary_path.read_text(encoding="utf-8"))
                indices = [int(i) for i in data.get("summary", [])]
                next_index = int(data.get("next_image_index", 0))
                dive = str(data.get("dive") or "")
            except (OSError, ValueError, TypeError, AttributeError) as err:  # AttributeError: JSON but not an object
                log.warning("store %s: %s unreadable (%s); rebuilding from the change log", self.dir, SUMMARY_FILE, err)
                indices = self._summary_from_changes()
        highest = self._highest_index_on_disk()
        self._next_index = max(next_index, highest + 1)
        for index in indices:
            held = self._read_frame(index)
            if held is None:
                log.warning("store %s: summary frame %d is missing on disk; dropped from the summary", self.dir, index)
                continue
            self._held[index] = held
            self._summary.append(index)
        self.dive = dive or secrets.token_hex(4)
        if not dive:
            self._write_summary()  # the new dive id is fixed now, not at the first frame
        self.stats.bytes_on_disk = self._disk_usage()

    def _summary_from_changes(self) -> list[int]:
        path = self.dir / CHANGES_FILE
        held: list[int] = []
        if not path.exists():
            return held
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue  # a line cut short by a crash
            if isinstance(entry, dict) and isinstance(entry.get("summary"), list):
                try:
                    held = [int(i) for i in entry["summary"]]
                except (TypeError, ValueError):
                    continue  # a damaged entry: the one before it stands
        return held

    def _highest_index_on_disk(self) -> int:
        highest = -1
        for path in self.frames_dir.glob("*.json"):
            try:
                highest = max(highest, int(path.stem))
            except ValueError:
                continue
        return highest

    def _read_frame(self, index: int) -> _Held | None:
        base = self.frames_dir / _name(index)
        try:
            sidecar = json.loads((base.with_suffix(".json")).read_text(encoding="utf-8"))
            feature = np.load(base.with_suffix(".npy"), allow_pickle=False)
            image = cv2.imread(str(base.with_suffix(".jpg")), cv2.IMREAD_COLOR)
        except (OSError, ValueError):
            return None
        if image is None or not isinstance(sidecar, dict):
            return None
        try:
            return self._held_from(sidecar, image, feature)
        except (KeyError, TypeError, ValueError):  # a sidecar edited by hand or damaged: that frame is dropped
            return None

    def _held_from(self, sidecar: dict[str, Any], image: np.ndarray, feature: np.ndarray) -> _Held:
        raw = None
        if sidecar.get("raw_file"):
            raw = cv2.imread(str(self.dir / sidecar["raw_file"]), cv2.IMREAD_COLOR)
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
        )
        return _Held(frame=frame, sidecar=sidecar, on_disk=True)

    # ---- what the rest of the companion asks ----------------------------------------------------------------
    def resume_state(self) -> ResumeState:
        """The summary to restore into the sampler (in summary order) and the next image index to hand out."""
        with self._lock:
            return ResumeState([self._held[i].frame for i in self._summary], self._next_index)

    @property
    def next_image_index(self) -> int:
        with self._lock:
            return self._next_index

    @property
    def summary(self) -> list[int]:
        with self._lock:
            return list(self._summary)

    def frame(self, index: int) -> SummaryFrame | None:
        """A frame by image index: the ones held in the summary, or any complete one still on disk."""
        with self._lock:
            held = self._held.get(index)
            if held is not None:
                return held.frame
        held = self._read_frame(index) if not self.memory_only else None
        return held.frame if held else None

    def frame_jpeg(self, index: int, raw: bool = False) -> bytes | None:
        """The stored JPEG of a frame as written (None: not on disk), so what the surface downloads over FTP is
        byte for byte what the vehicle keeps."""
        if self.memory_only:
            return None
        path = self.frames_dir / (f"{_name(index)}.raw.jpg" if raw else f"{_name(index)}.jpg")
        try:
            return path.read_bytes()
        except OSError:
            return None

    def sidecar(self, index: int) -> dict[str, Any] | None:
        with self._lock:
            held = self._held.get(index)
            if held is not None:
                return dict(held.sidecar)
        try:
            return json.loads((self.frames_dir / f"{_name(index)}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def index_document(self) -> dict[str, Any]:
        """The current summary with its tags (what summary.json holds)."""
        with self._lock:
            return {
                "version": FORMAT_VERSION,
                "dive": self.dive,
                "summary": list(self._summary),
                "next_image_index": self._next_index,
                "updated": time.time(),
                "frames": [self._held[i].sidecar for i in self._summary],
            }

    # ---- changes ----------------------------------------------------------------------------------------------
    def apply(self, event: SummaryEvent, *, tags: dict[str, Any] | None = None) -> None:
        """Record one summary change: save an added frame, forget a removed one, update the index and the log."""
        with self._lock:
            index = event.frame.image_index
            if event.kind == "added":
                sidecar = sidecar_for(event.frame, tags=tags)
                self._next_index = max(self._next_index, index + 1)
                held = _Held(frame=event.frame, sidecar=sidecar)
                self._held[index] = held
                self._write_frame(held)
            else:
                self._held.pop(index, None)
            if event.summary:
                self._summary = [i for i in event.summary if i in self._held]
            elif event.kind == "removed":
                self._summary = [i for i in self._summary if i != index]
            elif index not in self._summary:
                self._summary.append(index)
            self._append_change({"t": time.time(), "kind": event.kind, "image_index": index,
                                 "score": float(event.frame.score), "summary": list(self._summary)})
            self._write_summary()
            self._enforce_budget()

    def _write_frame(self, held: _Held) -> None:
        if self.memory_only:
            return
        frame = held.frame
        base = self.frames_dir / _name(frame.image_index)
        try:
            atomic_write(base.with_suffix(".jpg"), _encode_jpeg(frame.image))
            if frame.enhanced and frame.raw_image is not None and self.cfg.keep_raw:
                raw_path = self.frames_dir / f"{_name(frame.image_index)}.raw.jpg"
                atomic_write(raw_path, _encode_jpeg(frame.raw_image))
                held.sidecar["raw_file"] = f"frames/{raw_path.name}"
            atomic_write(base.with_suffix(".npy"), _npy_bytes(frame.feature))
            atomic_write(base.with_suffix(".json"), json.dumps(held.sidecar, indent=1).encode())
        except OSError as err:
            self._degrade(err)
            return
        held.on_disk = True
        self.stats.frames_written += 1

    def _write_summary(self) -> None:
        if self.memory_only:
            return
        try:
            atomic_write(self.dir / SUMMARY_FILE, json.dumps(self.index_document(), indent=1).encode())
        except OSError as err:
            self._degrade(err)

    def _append_change(self, entry: dict[str, Any]) -> None:
        if self.memory_only:
            return
        try:
            with open(self.dir / CHANGES_FILE, "a", encoding="utf-8") as fh:
                fh.write(json.dumps(entry) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as err:
            self._degrade(err)

    # ---- disk budget ------------------------------------------------------------------------------------------
    def _disk_usage(self) -> int:
        total = 0
        for directory in (self.dir, self.frames_dir):
            try:
                for entry in os.scandir(directory):
                    if entry.is_file(follow_symlinks=False):
                        total += entry.stat(follow_symlinks=False).st_size
            except OSError:
                continue
        return total

    def _enforce_budget(self) -> None:
        """Over budget: frames no longer in the summary go first, oldest first; the summary itself is kept."""
        if self.memory_only:
            return
        usage = self._disk_usage()
        if usage > self.budget_bytes:
            keep = set(self._summary)
            old = sorted({int(p.name[:6]) for p in self.frames_dir.glob("[0-9]*.*") if p.name[:6].isdigit()} - keep)
            for index in old:
                if usage <= self.budget_bytes:
                    break
                for path in self.frames_dir.glob(f"{_name(index)}.*"):
                    try:
                        size = path.stat().st_size
                        path.unlink()
                        usage -= size
                    except OSError:
                        continue
                self.stats.frames_pruned += 1
            if usage > self.budget_bytes:
                log.warning("store %s: the summary alone (%d bytes) exceeds the disk budget (%d bytes)",
                            self.dir, usage, self.budget_bytes)
        self.stats.bytes_on_disk = usage

    # ---- degrading ----------------------------------------------------------------------------------------------
    def _degrade(self, err: OSError) -> None:
        """A full or read-only disk: keep the summary in memory, say so once, never crash."""
        self.stats.write_errors += 1
        if self.memory_only:
            return
        self.memory_only = True
        reason = {errno.ENOSPC: "disk full", errno.EROFS: "read-only file system",
                  errno.EACCES: "permission denied", errno.EDQUOT: "disk quota exceeded"}.get(
            err.errno, err.strerror or str(err))
        self.memory_only_reason = reason
        log.warning("store %s: %s; keeping the summary in memory only (frames saved before are intact)",
                    self.dir, reason)

    def describe(self) -> dict[str, Any]:
        with self._lock:
            return {
                "dir": str(self.dir),
                "dive": self.dive,
                "memory_only": self.memory_only,
                "reason": self.memory_only_reason,
                "summary": list(self._summary),
                "next_image_index": self._next_index,
                "frames_written": self.stats.frames_written,
                "frames_pruned": self.stats.frames_pruned,
                "bytes_on_disk": self.stats.bytes_on_disk,
            }
