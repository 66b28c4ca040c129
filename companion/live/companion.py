"""The live companion: one process joining the camera, the vision core, the vehicle link and the surface link.

Start-up order, and why:

1. the store (resume: the summary, its features and the next image index must be known before anything runs);
2. the encoder and the pipeline, restored from the store (the slow part; nothing is on the wire yet, so a bad
   model fails before the vehicle sees a half-started camera);
3. the MAVLink link, the telemetry and the surface link (the camera component now answers, with the resumed
   summary already in place);
4. the capture and inference threads, then READY=1 to systemd and the health monitor's watchdog pings.

Shutdown runs the other way round; the store is always consistent on disk, so a SIGKILL loses nothing saved.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion import __version__
from companion.config import Config, build_config
from companion.live.health import Health
from companion.live.loops import CaptureLoop, InferenceLoop, LiveCounters
from companion.live.notify import Notifier
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.sources.retrying import RetryingSource
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.storage.params_file import ParamsFile
from companion.storage.store import Store
from companion.vision.events import SummaryEvent

log = logging.getLogger(__name__)

LIVE_PREFIXES = ("/dev/video", "/dev/v4l/", "v4l2://", "rtsp://", "rtsps://", "udp://")
KEEPER_PATH = "/store/summary.json"
"""The summary the keeper holds, with its recent history, over FTP (audits; see SummaryKeeper.document)."""
CAPTURE_QUEUE = 4
"""Frames waiting for inference; beyond this the oldest is dropped (at 5 fps: under a second of backlog)."""


def is_live_uri(uri: str) -> bool:
    return uri.startswith(LIVE_PREFIXES)


@dataclass
class LiveOptions:
    notifier: Notifier | None = None
    """sd_notify (built from the environment by the command line; None: silent)."""
    make_encoder: Callable[[Any], Any] | None = None
    """Encoder factory override (tests); default companion.vision.encoders.factory.make_encoder."""
    params_path: str | None = None
    """Where live-tuned parameters persist (default: in the store directory)."""


class LiveCompanion:
    def __init__(self, cfg: Config, options: LiveOptions | None = None) -> None:
        self.cfg = cfg
        self.options = options or LiveOptions()
        self.notifier = self.options.notifier or Notifier(None)
        self.health = Health(cfg.health.stall_after_s)
        self.counters = LiveCounters()
        self.stop_event = threading.Event()
        self.queue: DropOldestQueue[Frame] = DropOldestQueue(CAPTURE_QUEUE)
        self.started_at = time.monotonic()
        self.store: Store | None = None
        self.keeper: SummaryKeeper | None = None
        self.saved_params: dict[str, float] = {}
        self.marks = SavedMarks()
        """The operator's marks in force (image indices), and the query they were given under."""
        self.pipeline = None
        self.encoder = None
        self.link = None
        self.telemetry = None
        self.surface = None
        self.source: RetryingSource | None = None
        self.capture: CaptureLoop | None = None
        self.inference: InferenceLoop | None = None
        self.selective = None
        self.enhance_worker = None
        self._monitor: threading.Thread | None = None
        self._last_ping = 0.0
        self.watchdog_pings = 0
        self.watchdog_withheld = 0
        self._stuck: list[str] = []

    # ---- start-up -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        cfg = self.cfg
        # a settings file from a newer version stops the start before anything is opened or written
        self.saved_params = self._params_file().load()
        self.store = Store(cfg.store)
        saved_marks = self._marks_file().load()
        resume = self.store.resume_state()
        if resume.frames:
            log.info("resuming with %d summary frame(s); next image index %d", len(resume.frames),
                     resume.next_image_index)
        self._build_pipeline(resume)
        self._restore_marks(saved_marks)
        self._start_vehicle(resume.next_image_index)
        self._start_loops()
        self._monitor = threading.Thread(target=self._monitor_loop, name="health", daemon=True)
        self._monitor.start()
        self.notifier.ready(self.status_line())
        log.info("companion running: source %s, encoder %s, mavlink %s, store %s", cfg.source.uri,
                 getattr(self.encoder, "name", "?"), cfg.mavlink.connection, self.store.dir)

    def _build_pipeline(self, resume) -> None:
        from companion.vision.pipeline import Pipeline

        factory = self.options.make_encoder
        if factory is None:
            from companion.vision.encoders.factory import make_encoder as factory
        self.encoder = factory(self.cfg.encoder)
        cfg = self.cfg
        if cfg.enhance.mode == "selective":
            # the pipeline samples enhanced frames behind a tau_ses gate; tau_ss is applied before the worker
            from companion.live.enhance_worker import SelectiveStage
            from companion.vision.enhancers.factory import make_enhancer
            from companion.vision.presampler import PreSampler

            data = cfg.model_dump()
            data["enhance"]["mode"] = "none"
            data["queries"]["tau_ss"] = cfg.enhance.tau_ses
            data["gate"]["mode"] = "none"  # candidates arrive sparse and already chosen: never skip one
            self.pipeline = Pipeline.from_config(build_config(data, origin="enhance"), self.encoder,
                                                 first_image_index=resume.next_image_index)
            self.keeper = self._make_keeper()
            raw = PreSampler(self.encoder, cfg.queries.positive, cfg.queries.negatives, cfg.queries.tau_ss)
            enhancer = make_enhancer(cfg.enhance, device=cfg.encoder.device)
            self.selective = SelectiveStage(self.pipeline, raw, enhancer, queue_size=cfg.enhance.queue,
                                            lock=self.keeper.lock)
        else:
            self.pipeline = Pipeline.from_config(cfg, self.encoder, first_image_index=resume.next_image_index)
            self.keeper = self._make_keeper()

        def restore() -> list[SummaryEvent]:
            removed = self.pipeline.restore(resume.frames)  # a smaller K than before the restart trims at once
            self.pipeline.next_image_index = max(self.pipeline.next_image_index, resume.next_image_index)
            return removed

        self.keeper.change(restore)

    def _make_keeper(self) -> SummaryKeeper:
        def tags() -> dict[str, Any]:
            return {"query": self.pipeline.presampler.positive,  # the live query, which the surface may change
                    "encoder": getattr(self.encoder, "name", ""), "source": self.cfg.source.uri}

        return SummaryKeeper(self.pipeline, self.store, tags=tags, publish=self._publish)

    def _publish(self, event: SummaryEvent) -> None:
        if self.surface is not None:
            self.surface.publish(event)

    def _params_file(self) -> ParamsFile:
        return ParamsFile(self.options.params_path or Path(self.cfg.store.dir) / "params.json", version=__version__)

    def _marks_file(self) -> MarksFile:
        return MarksFile(self.store.dir / "marks.json", version=__version__)

    def _start_vehicle(self, image_count: int) -> None:
        cfg = self.cfg
        if not cfg.mavlink.connection:
            log.warning("mavlink.connection is null: no vehicle link, no surface link (store only)")
            return
        from companion.live.tunables import default_params
        from vehicle.camera.downlink import Downlink
        from vehicle.link.connection import MavLink

        self.link = MavLink(cfg.mavlink.connection, cfg.mavlink, name="companion")
        self.link.healthy = self.health.healthy
        self.telemetry = _make_telemetry(self.link, cfg)
        params_file = self._params_file()
        specs = default_params(cfg)
        defaults = {spec.name: spec.value for spec in specs}  # before the saved values are applied to the specs
        self.surface = Downlink(
            self.link, cfg.surface, params=specs, saved_params=self.saved_params,
            persist_params=params_file.save,
            loader=self.store.frame, image_count=image_count, stored_jpeg=self.store.frame_jpeg,
            queries=(cfg.queries.positive, list(cfg.queries.negatives)), version=__version__,
            dive=self.store.dive,
        )
        self.surface.on_param_changed(self._on_param, replay=False)
        for name, value in self.surface.params.restored.items():  # what the operator set last time
            try:
                self._on_param(name, value)
            except ValueError as err:  # refused now (e.g. MERL_ENHANCE after enhance.mode became none)
                log.warning("saved parameter %s=%g not applied: %s", name, value, err)
                self.surface.params.set(name, defaults[name])  # served and saved as what is in force
        if self.telemetry is not None and hasattr(self.telemetry, "on_notice"):
            self.telemetry.on_notice(self.surface.event)  # e.g. "no position source", once, as a STATUSTEXT
        self.surface.on_queries_changed(self._on_queries)
        self.surface.on_marks_changed(self._on_marks)
        self.surface.set_marks(self.marks.like, self.marks.unlike)
        self.surface.tree.put(KEEPER_PATH, lambda: json.dumps(self.keeper.document()).encode())
        self.link.on_autopilot(self._on_autopilot)
        self.link.start()
        if self.telemetry is not None and hasattr(self.telemetry, "start"):
            self.telemetry.start()
        self.surface.start()
        self.keeper.republish()  # the resumed summary is on the FTP tree again

    def _start_loops(self) -> None:
        from companion.sources.factory import open_source

        cfg = self.cfg.source
        self.source = RetryingSource(
            lambda: open_source(cfg), name=cfg.uri, live=is_live_uri(cfg.uri), loop=False,
            initial_s=cfg.retry_initial_s, max_s=cfg.retry_max_s, on_state=self._on_source_state,
            beat=lambda: self.health.beat("capture"),
        )
        self.capture = CaptureLoop(self.source, self.queue, self.health, self.counters, self.stop_event)
        self.inference = InferenceLoop(
            self.pipeline, self.queue, self.health, self.counters, self.stop_event,
            batch=self.cfg.encoder.batch, pose_at=self._pose_at, keeper=self.keeper, selective=self.selective,
        )
        if self.selective is not None:
            from companion.live.enhance_worker import EnhanceWorker

            self.enhance_worker = EnhanceWorker(self.selective, self.health, self.counters, self.stop_event,
                                                batch=self.cfg.encoder.batch, keeper=self.keeper)
            self.enhance_worker.start()
        self.inference.start()
        self.capture.start()

    # ---- the data path ------------------------------------------------------------------------------------------
    def _pose_at(self, t: float):
        if self.telemetry is None:
            return None
        try:
            return self.telemetry.pose_at(t)
        except Exception:  # noqa: BLE001 - a pose lookup problem must not cost the frame
            log.debug("pose lookup failed", exc_info=True)
            return None

    # ---- live tuning from the surface -------------------------------------------------------------------------
    def _on_param(self, name: str, value: float) -> None:
        """A MERL_* change from the surface, applied by the keeper between two batches (ValueError refuses it)."""
        if name == "MERL_ENHANCE":
            self._check_enhance(bool(value))
        if name == "MERL_GATE" and self.selective is not None:
            self._refuse(name, "the frame gate does not run with enhance.mode selective")
        if name in ("MERL_TAU_SS", "MERL_TAU_SES", "MERL_K", "MERL_ENHANCE", "MERL_GATE"):
            self.keeper.change(lambda: self._tune(name, value))
            log.info("parameter %s set to %g", name, value)

    def _tune(self, name: str, value: float) -> list[SummaryEvent]:
        """Runs inside the keeper: the pipeline changes and the trims it causes reach the store together."""
        sel = self.selective
        if name == "MERL_TAU_SS":
            if sel is not None:
                sel.raw.tau_ss = value
                if not sel.on:
                    self.pipeline.tau_ss = value
            else:
                self.pipeline.tau_ss = value
        elif name == "MERL_TAU_SES":
            self.pipeline.tau_ses = value
            if sel is not None and sel.on:
                self.pipeline.tau_ss = value  # the gate on enhanced frames
        elif name == "MERL_K":
            return self.pipeline.set_k(int(value))
        elif name == "MERL_GATE":  # 0: off; otherwise the difference threshold in grey levels
            self.pipeline.gate.mode = "difference" if value > 0 else "none"
            self.pipeline.gate.threshold = max(0.0, float(value))
        elif name == "MERL_ENHANCE":
            if sel is not None:
                sel.on = bool(value)
                self.pipeline.tau_ss = self.pipeline.tau_ses if value else sel.raw.tau_ss
            else:  # enhance.mode always: every frame enhanced, or none
                self.pipeline.enhance_mode = "always" if value else "none"
        return []

    def _refuse(self, name: str, why: str, detail: str = "") -> None:
        """Say on the surface why a parameter change is refused (``why``, short), then refuse it with ``detail``
        for the log (the value stays as it was)."""
        if self.surface is not None:
            from vehicle.camera import status as st

            self.surface.event(f"{name} refused: {why}"[:50], st.WARNING)
        raise ValueError(detail or why)

    def _embed_ahead(self, positive: str, negatives: list[str]) -> None:
        """Embed new queries before the keeper's lock is taken: with CLIP a text not yet cached is encoded by a
        child process (seconds), which must not hold up the encode loop; set_queries then finds it cached."""
        from companion.errors import MerlionError
        from companion.vision.presampler import GENERIC_NEGATIVE

        negatives = [n.strip() for n in negatives if n.strip()]
        if positive.strip():
            try:
                self.pipeline.presampler.encoder.encode_texts([positive.strip(), *(negatives or [GENERIC_NEGATIVE])])
            except MerlionError:
                pass  # set_queries, under the lock, raises it or falls back exactly as before

    def _check_enhance(self, on: bool) -> None:
        """MERL_ENHANCE=1 needs an enhancer, loaded at start only when enhance.mode asks for one: refuse, and
        say why on the surface, rather than accept a value that changes nothing."""
        if on and self.cfg.enhance.mode == "none":
            self._refuse("MERL_ENHANCE", "enhance.mode is none", "enhance.mode is none (no enhancer loaded); set "
                         "enhance.mode: selective or always and restart")

    def _on_queries(self, positive: str, negatives: list[str]) -> None:
        self._embed_ahead(positive, negatives)

        def set_queries() -> None:
            self.pipeline.presampler.set_queries(positive, negatives)
            if self.selective is not None:
                self.selective.raw.set_queries(positive, negatives)

        self.keeper.change(set_queries)
        log.info("queries set: %r against %r", positive, negatives)
        if self.marks:  # marks teach what this query should find: a new query starts untaught
            self._on_marks([], [])
            log.info("marks cleared with the queries")
            if self.surface is not None:
                self.surface.event("Marks cleared with the queries")

    # ---- the operator's marks -----------------------------------------------------------------------------------
    def _on_marks(self, like: list[int], unlike: list[int]) -> None:
        """Marks from the surface (image indices): score by them from the next batch on, and keep them on disk.

        ValueError (a frame the store no longer has) refuses the upload; the surface gets a NAK.
        """
        self._apply_marks(like, unlike)
        self.marks = SavedMarks(list(like), list(unlike), self.pipeline.presampler.positive)
        if self.surface is not None:
            self.surface.set_marks(like, unlike)
        try:
            if self.marks:
                self._marks_file().save(self.marks)
            else:
                self._marks_file().clear()
        except OSError as err:  # a memory-only store: the marks hold for this run
            log.warning("marks not saved: %s", err)
        log.info("marks set: like %s, unlike %s", like, unlike)

    def _restore_marks(self, saved: SavedMarks) -> None:
        """Re-apply the marks an earlier run saved, if they were given under the query in force now."""
        if not saved:
            return
        if saved.query != self.pipeline.presampler.positive:
            log.info("saved marks were given for %r, not %r: not applied", saved.query,
                     self.pipeline.presampler.positive)
            return
        try:
            self._apply_marks(saved.like, saved.unlike)
        except ValueError as err:
            log.warning("saved marks not applied: %s", err)
            return
        self.marks = saved
        log.info("restored marks: %d like, %d unlike", len(saved.like), len(saved.unlike))

    def _apply_marks(self, like: list[int], unlike: list[int]) -> None:
        """Embed the marked frames' stored images and switch the pre-sampler(s) to the combined score.

        Runs inside the keeper: the encoder is the inference loop's, and the next batch sees the new score.
        """
        from companion.vision.feedback import Marks

        def images(indices: list[int]) -> list:
            found = []
            for index in indices:
                frame = self.store.frame(index)
                if frame is None or frame.image is None:
                    raise ValueError(f"image {index} is not in the store")
                found.append(self.pipeline.prepare(frame.image))
            return found

        def apply() -> None:
            if like or unlike:
                marks = Marks.from_images(self.encoder, images(like), images(unlike))
            else:
                marks = Marks(np.zeros((0, 1)), np.zeros((0, 1)))
            self.pipeline.presampler = _marked(self.pipeline.presampler, marks)
            if self.selective is not None:
                self.selective.raw = _marked(self.selective.raw, marks)

        self.keeper.change(apply)

    def _on_autopilot(self, alive: bool) -> None:
        if alive:
            log.info("autopilot heartbeat back")
        else:
            log.warning("autopilot heartbeat lost; frames are tagged stale until it returns")
        if self.surface is not None:
            from vehicle.camera import status as st

            self.surface.event(*st.link_text(alive))

    def _on_source_state(self, state: str, detail: str) -> None:
        if self.surface is None:
            return
        from vehicle.camera import status as st

        if state == "retrying":
            self.surface.event(*st.camera_text(False))
        elif state == "running" and self.source is not None and self.source.failures:
            self.surface.event(*st.camera_text(True))
        elif state == "ended":
            self.surface.event("Source ended; still serving", st.NOTICE)

    # ---- health, status, watchdog ------------------------------------------------------------------------------
    def _monitor_loop(self) -> None:
        ping_every = self.notifier.ping_interval_s or 1.0
        while not self.stop_event.wait(min(1.0, ping_every)):
            stuck = self.health.stuck()
            if stuck:
                self.watchdog_withheld += 1
                if stuck != self._stuck:
                    log.warning("stage(s) %s stuck for over %.0f s: no watchdog ping until it moves again",
                                ", ".join(stuck), self.health.stall_after_s)
            elif self._stuck:
                log.warning("stage(s) %s moving again: watchdog pings resume", ", ".join(self._stuck))
            self._stuck = stuck
            if not stuck and time.monotonic() - self._last_ping >= ping_every:
                self.notifier.watchdog()
                self.watchdog_pings += 1
                self._last_ping = time.monotonic()
            self._update_status()

    def _update_status(self) -> None:
        depth = None
        if self.telemetry is not None:
            pose = self._pose_at(time.time())
            depth = getattr(pose, "depth_m", None) if pose is not None and not pose.stale else None
        if self.surface is not None:
            self.surface.update_status(fps=self.counters.fps(), score=self.counters.last_score,
                                       summary=len(self.store.summary), depth_m=depth)
        self.notifier.status(self.status_line())

    def status_line(self) -> str:
        c = self.counters
        src = self.source.state if self.source is not None else "starting"
        ap = "up" if self.link is not None and self.link.autopilot_alive else "down"
        store = "memory-only" if self.store is not None and self.store.memory_only else "ok"
        summary = len(self.store.summary) if self.store is not None else 0
        return (f"source {src}; {c.fps():.1f} fps; seen {c.frames_seen} passed {c.frames_passed}; "
                f"summary {summary}/{self.cfg.sampler.k}; dropped {self.queue.dropped}; autopilot {ap}; store {store}")

    def report(self) -> dict[str, Any]:
        """Numbers for the demo report, the soak bench and logs."""
        c = self.counters
        link = self.link
        return {
            "frames_seen": c.frames_seen, "frames_scored": c.frames_scored, "frames_passed": c.frames_passed,
            "frames_enhanced": c.frames_enhanced, "frames_dropped": self.queue.dropped,
            "enhance_dropped": self.selective.queue.dropped if self.selective is not None else 0,
            "frames_lost": self.source.lost if self.source is not None else 0,
            "summary": self.store.summary if self.store is not None else [],
            "summary_added": c.summary_added, "summary_removed": c.summary_removed,
            "inference_errors": c.inference_errors,
            "bytes_sent": link.tx_bytes if link is not None else 0,
            "bytes_received": link.rx_bytes if link is not None else 0,
            "rx_bad": link.rx_bad if link is not None else 0,
            "signing": link.signing.stats() if link is not None else {"enabled": False},
            "source_state": self.source.state if self.source is not None else "",
            "source_failures": self.source.failures if self.source is not None else 0,
            "store": self.store.describe() if self.store is not None else {},
            "encoder": getattr(self.encoder, "name", ""),
            "watchdog_pings": self.watchdog_pings, "watchdog_withheld": self.watchdog_withheld,
            "uptime_s": round(time.monotonic() - self.started_at, 1),
        }

    # ---- running and stopping -----------------------------------------------------------------------------------
    def run(self, duration: float | None = None, stop: threading.Event | None = None) -> None:
        """Block until ``stop`` is set, ``duration`` passes, or stop() is called."""
        deadline = None if duration is None else time.monotonic() + duration
        waiter = stop or self.stop_event
        while not self.stop_event.is_set():
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            if waiter.wait(0.5 if left is None else min(0.5, left)):
                break

    def stop_pipeline(self) -> None:
        """Stop capture and inference (the batch in hand finishes); the links keep serving."""
        self.stop_event.set()
        self.queue.close()
        if self.source is not None:
            self.source.close()
        if self.selective is not None:
            self.selective.queue.close()
        for thread in (self.capture, self.inference, self.enhance_worker, self._monitor):
            if thread is not None and thread.is_alive():
                thread.join(timeout=15)

    def drain(self, timeout: float) -> bool:
        """Wait (at most ``timeout``) until the thumbnails already queued for the surface are on the wire."""
        if self.surface is None:
            return True
        from vehicle.link.budget import Priority

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.surface.budget.pending(Priority.THUMBNAIL) == 0 and self.surface.budget.pending(
                    Priority.STATUS) == 0:
                return True
            time.sleep(0.1)
        return False

    def stop(self) -> None:
        """Finish the batch in hand, then close everything in reverse order."""
        self.notifier.stopping()
        self.stop_pipeline()
        if self.surface is not None:
            self.surface.stop()
        if self.telemetry is not None and hasattr(self.telemetry, "stop"):
            self.telemetry.stop()
        if self.link is not None:
            self.link.stop()
        self.notifier.close()


def _marked(presampler, marks):
    """``presampler`` scoring with ``marks`` (wrapped once; later marks, or none, replace the examples)."""
    from companion.vision.feedback import MarkedPreSampler

    if isinstance(presampler, MarkedPreSampler):
        presampler.set_marks(marks)
        return presampler
    return MarkedPreSampler(presampler, marks) if len(marks) else presampler


def _make_telemetry(link, cfg: Config):
    """The vehicle's pose history attached to the link (vehicle/autopilot/telemetry.py)."""
    from vehicle.autopilot.telemetry import VehicleTelemetry

    return VehicleTelemetry(link, cfg.telemetry)
