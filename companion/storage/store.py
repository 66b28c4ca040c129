"""On-board storage of the summary: survives crashes, reboots, full and read-only disks.

Layout of the store directory::

    frames/000042.jpg        the summary frame at full resolution (the enhanced one when enhancement ran)
    frames/000042.raw.jpg    the frame before enhancement (when enhanced and store.keep_raw)
    frames/000042.npy        the sampler feature, so a restart resumes with the same summary
    frames/000042.json       the sidecar: tags, pose, score, times; written last, so it marks a complete frame
    summary.json             the current summary (image indices), the next image index and the dive id
    changes.jsonl            append-only log of every change (one JSON object a line, ``change_log``)
    next_index               the next image index, persisted in place before an index is announced
    lock                     flock'ed by the one live process writing the store (``store_lock``), with its pid

Every file is written atomically (temp file, fsync, rename, fsync of the directory), so a crash leaves either the
old file or the new one, never half of one. When the disk is full or read-only the store keeps going in memory
and says so once (``store_health``: to the log and to its listeners, which tell the surface); the vehicle keeps
working and what was saved before stays intact. It tries the disk again every few seconds, and once the disk takes
writes again it writes what it kept in memory and goes on on disk. An image index is persisted
(``index_reservation``) before it is announced, so no later run hands it out again under the same dive id; a run
that cannot persist even that (a read-only disk at start, or a remount read-only mid-run) announces under a new
dive id of its own from that frame on (``DiveIndex``).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.atomic_write import TMP_PREFIX, atomic_write
from companion.config import StoreConfig
from companion.storage.change_log import ChangeLog
from companion.storage.frame_files import (
    FORMAT_VERSION,
    DamagedFrame,
    HeldFrame,
    encoder_of,
    frame_name,
    load_frame,
    read_frame,
    read_no_link,
    sidecar_for,
    write_feature_files,
    write_frame_files,
)
from companion.storage.index_reservation import MAX_INDEX, DiveIndex, valid_index
from companion.storage.store_health import Listener, StoreHealth
from companion.storage.summary_file import read_summary_file
from companion.storage.versioned import upgrade
from companion.vision.events import SummaryEvent, SummaryFrame
from vehicle.camera.storage import StorageSpace

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
CHANGES_FILE = "changes.jsonl"
NEXT_INDEX_FILE = "next_index"


@dataclass
class StoreStats:
    frames_written: int = 0
    frames_pruned: int = 0
    write_errors: int = 0
    bytes_on_disk: int = 0


@dataclass
class ResumeState:
    """What a restart continues from."""

    frames: list[SummaryFrame] = field(default_factory=list)
    next_image_index: int = 0
    encoders: dict[int, str] = field(default_factory=dict)
    """The encoder each frame's feature was made with, by image index ("": not recorded, an older store)."""


def refuse_newer(directory: Path) -> None:
    """A store written by a newer merlion is neither read as ours nor touched: stop (NewerFileError). Only reads,
    so the companion asks it before it takes the store's lock (which writes the lock file)."""
    path = directory / SUMMARY_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return  # absent or damaged: _load rebuilds from the change log
    if isinstance(data, dict) and isinstance(data.get("version"), int) and data["version"] > FORMAT_VERSION:
        upgrade(path, data, current=FORMAT_VERSION, migrations={})


class Store:
    """The summary on disk, kept in step with SummaryEvents; thread-safe."""

    def __init__(self, cfg: StoreConfig, *, directory: str | os.PathLike[str] | None = None,
                 guard: Callable[[], None] | None = None) -> None:
        """``guard``: asked before each change is written (``StoreLock.check``); raising ``StoreReplaced`` there
        makes the store memory-only for good, so it never writes into a folder another process took."""
        self.cfg = cfg
        self._guard = guard
        self.dir = Path(directory if directory is not None else cfg.dir)
        self.frames_dir = self.dir / "frames"
        self.budget_bytes = int(cfg.disk_budget_mb * 1024 * 1024)
        self.stats = StoreStats()
        self.health = StoreHealth(self.dir)
        self._index = DiveIndex(self.dir / NEXT_INDEX_FILE, self.dir)
        self._changes = ChangeLog(self.dir / CHANGES_FILE)
        self._lock = threading.RLock()
        self._held: dict[int, HeldFrame] = {}
        self._summary: list[int] = []
        self._next_index = 0
        self._open()

    @property
    def dive(self) -> str:
        """This store's dive id: made when the store is created (or its summary file is gone), kept across
        restarts, so the surface can tell a new dive's image 0 from the last dive's; a new one whenever the next
        image index cannot be persisted (``DiveIndex``)."""
        return self._index.dive

    @property
    def dive_changes(self) -> int:
        """Dive ids given up during this run because the next image index could not be persisted."""
        return self._index.changes

    @property
    def memory_only(self) -> bool:
        return self.health.memory_only

    @property
    def memory_only_reason(self) -> str:
        return self.health.reason

    def on_health(self, listener: Listener) -> None:
        """``listener(memory_only, reason)`` when the store leaves the disk or comes back (called under the
        store's lock: it must only queue, as the surface link's ``event`` does)."""
        self.health.on_change(listener)

    # ---- start-up -------------------------------------------------------------------------------------------
    def _open(self) -> None:
        refuse_newer(self.dir)
        try:
            self.frames_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            if not self.frames_dir.is_dir():
                self._degrade(err)  # says it; nothing (the next image index neither) can be written here
                self._index.without_disk()
                return
        try:
            self._clean_temp_files()
            self._check_writable()
            self._changes.end_torn_tail()
        except OSError as err:
            self._degrade(err)  # a full or read-only disk: what is there is still resumed, in memory
        self._load()

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
        saved = read_summary_file(self.dir / SUMMARY_FILE)  # a damaged field is dropped alone, with a warning
        indices = saved.summary if saved.summary is not None else self._changes.last_summary()
        beyond = [i for i in indices if not valid_index(i)]
        if beyond:  # a change log of a run from before the int32 limit was kept: MAVLink cannot announce them
            log.warning("store %s: image(s) %s dropped from the summary: past %d, the last index MAVLink carries",
                        self.dir, beyond, MAX_INDEX)
            indices = [i for i in indices if valid_index(i)]
        next_index, dive = saved.next_index, saved.dive
        highest = self._highest_index_on_disk()
        self._next_index = max(next_index, highest + 1, self._index.reservation.load())
        for index in indices:
            try:
                held = load_frame(self.dir, index)
            except DamagedFrame as err:  # that frame alone: the rest of the summary resumes
                log.warning("store %s: summary frame %d dropped from the summary: %s", self.dir, index, err)
                continue
            self._held[index] = held
            self._summary.append(index)
        refused = self._index.start(dive, self._next_index)
        if refused is not None:
            self.health.degrade(refused)
        if not dive or saved.dropped or beyond:
            self._write_summary()  # the new dive id is fixed now, not at the first frame; a dropped field goes
        self.stats.bytes_on_disk = self._disk_usage()
        if self._next_index > MAX_INDEX:
            log.error("store %s: every image index MAVLink can carry (0-%d) is used: no new frame can enter the "
                      "summary (the one held is still served); move the store aside to start a new one", self.dir,
                      MAX_INDEX)

    def _highest_index_on_disk(self) -> int:
        """The highest image index a sidecar is named for; one past the int32 limit (a run from before it was
        kept) counts as the limit, so the next index is ``USED_UP`` and those files are never written over."""
        highest = -1
        for path in self.frames_dir.glob("*.json"):
            if path.stem.isascii() and path.stem.isdigit():
                highest = max(highest, min(int(path.stem), MAX_INDEX))
        return highest

    # ---- what the rest of the companion asks ----------------------------------------------------------------
    def resume_state(self) -> ResumeState:
        """The summary to restore into the sampler (in summary order) and the next image index to hand out."""
        with self._lock:
            held = [self._held[i] for i in self._summary]
            return ResumeState([h.frame for h in held], self._next_index,
                               {h.frame.image_index: encoder_of(h.sidecar) for h in held})

    def _still_ours(self) -> bool:
        """The folder at the path is still the one this run locked (no guard: assumed); if not, memory-only."""
        if self.health.lost:
            return False
        if self._guard is not None:
            try:
                self._guard()
            except OSError as err:
                self._degrade(err)
                return False
        return True

    def replace_feature(self, index: int, feature: np.ndarray, encoder: str) -> None:
        """A held frame's sampler feature made again by ``encoder`` (a resume under another encoder): in memory,
        and on disk unless memory-only (the .npy, then the sidecar naming the encoder, then summary.json, which
        lists the sidecars: it names the encoder in use from the start of the run, not from its first frame)."""
        with self._lock:
            held = self._held[index]
            held.frame.feature = feature
            if not isinstance(held.sidecar.get("tags"), dict):
                held.sidecar["tags"] = {}
            held.sidecar["tags"]["encoder"] = encoder
            if not self._still_ours() or self.memory_only or not held.on_disk:
                return
            try:
                write_feature_files(self.dir, held)
            except OSError as err:
                self._degrade(err)
                return
            self._write_summary()

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
        held = read_frame(self.dir, index) if not self.memory_only else None
        return held.frame if held else None

    def frame_jpeg(self, index: int, raw: bool = False) -> bytes | None:
        """The stored JPEG of a frame as written (None: not on disk), so what the surface downloads over FTP is
        byte for byte what the vehicle keeps; never through a link."""
        if self.memory_only:
            return None
        return read_no_link(self.frames_dir / (f"{frame_name(index)}.raw.jpg" if raw else f"{frame_name(index)}.jpg"))

    def sidecar(self, index: int) -> dict[str, Any] | None:
        with self._lock:
            held = self._held.get(index)
            if held is not None:
                return dict(held.sidecar)
        try:
            return json.loads((self.frames_dir / f"{frame_name(index)}.json").read_text(encoding="utf-8"))
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
            if self._still_ours() and self.health.retry_due():
                self._recover()
            index = event.frame.image_index
            if event.kind == "added" and not valid_index(index):  # the pipeline stops at the limit: a last guard
                log.error("store %s: image index %d not stored: MAVLink carries 0-%d", self.dir, index, MAX_INDEX)
                return
            if event.kind == "added":
                sidecar = sidecar_for(event.frame, tags=tags)
                self._next_index = max(self._next_index, index + 1)
                self._persist_next_index()
                held = HeldFrame(frame=event.frame, sidecar=sidecar)
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

    def _persist_next_index(self) -> None:
        """Before the index is announced (the keeper publishes after ``apply``): an in-place write, which a full
        disk still takes; when it fails the dive id changes first (``DiveIndex.reserve``)."""
        if self.health.lost:  # the path is another store's now: its next_index is not this run's to raise
            if not self._index.refused:
                self._index.give_up(self._next_index - 1, "folder replaced")
            return
        err = self._index.reserve(self._next_index)
        if err is not None:
            self._degrade(err)

    def retry(self) -> bool:
        """Try the disk again if the store is memory-only and a retry is due (the companion calls this once a
        second; ``apply`` does too); True when the store is on disk."""
        with self._lock:
            if self.health.retry_due() and self._still_ours():
                self._recover()
            return not self.memory_only

    def _recover(self) -> None:
        """Back to disk: what was kept in memory (frames, the next index, the summary) is written, then the store
        goes on on disk; any failure leaves it memory-only, quietly (it said so already)."""
        pending = [self._held[i] for i in self._summary if not self._held[i].on_disk]  # what a restart needs
        try:
            self._check_writable()
            self._index.recovered(self._next_index)
            for held in pending:
                write_frame_files(self.dir, held, keep_raw=self.cfg.keep_raw)
            self._write_summary_file()
            self._changes.append({"t": time.time(), "kind": "back_on_disk", "summary": list(self._summary)})
        except OSError as err:
            self.health.write_errors += 1
            log.debug("store %s: still not writable (%s)", self.dir, err)
            return
        for held in pending:
            held.on_disk = True
            self.stats.frames_written += 1
        self.health.recovered(len(pending))
        self._enforce_budget()

    def _write_frame(self, held: HeldFrame) -> None:
        if self.memory_only:
            return
        try:
            write_frame_files(self.dir, held, keep_raw=self.cfg.keep_raw)
        except OSError as err:
            self._degrade(err)
            return
        held.on_disk = True
        self.stats.frames_written += 1

    def _write_summary(self) -> None:
        if self.memory_only:
            return
        try:
            self._write_summary_file()
        except OSError as err:
            self._degrade(err)

    def _write_summary_file(self) -> None:
        atomic_write(self.dir / SUMMARY_FILE, json.dumps(self.index_document(), indent=1).encode())

    def _append_change(self, entry: dict[str, Any]) -> None:
        if self.memory_only:
            return
        try:
            self._changes.append(entry)
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
            # the index is the name up to its first dot: six digits and more (frame_name pads, never cuts)
            stems = {p.name.split(".", 1)[0] for p in self.frames_dir.glob("[0-9]*.*")}
            old = sorted({int(n) for n in stems if n.isascii() and n.isdigit()} - keep)
            for index in old:
                if usage <= self.budget_bytes:
                    break
                for path in self.frames_dir.glob(f"{frame_name(index)}.*"):
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

    def space(self) -> StorageSpace:
        """The store's room as the camera reports it (STORAGE_INFORMATION): its disk budget, what its files use,
        and what is left of the budget, no more than the file system has free (0 while memory-only: nothing more
        reaches the disk)."""
        used = self.stats.bytes_on_disk
        left = max(0, self.budget_bytes - used)
        if self.memory_only:
            left = 0
        else:
            try:
                left = min(left, shutil.disk_usage(self.dir).free)
            except OSError:
                left = 0
        return StorageSpace(total=self.budget_bytes, used=used, available=left)

    # ---- degrading ----------------------------------------------------------------------------------------------
    def _degrade(self, err: OSError) -> None:
        """A full or read-only disk: keep the summary in memory, say so once, never crash."""
        self.stats.write_errors += 1
        self.health.degrade(err)

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
                "back_on_disk": self.health.recoveries,
                "frames_in_memory_only": sum(1 for i in self._summary if not self._held[i].on_disk),
                "bytes_on_disk": self.stats.bytes_on_disk,
            }
