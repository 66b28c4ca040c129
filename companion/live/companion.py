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

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion import __version__
from companion.config import Config, build_config
from companion.live.control.context import ControlContext
from companion.live.control.marks import MarksHandler
from companion.live.control.notices import AutopilotNotice, source_notice
from companion.live.control.params import ParamHandler, default_params
from companion.live.control.queries import QueriesHandler, follow_saved_queries
from companion.live.control.shutter import ShutterHandler
from companion.live.control.summary_file import keeper_document, serve_keeper_document
from companion.live.enhance_worker import EnhanceWorker, SelectiveStage
from companion.live.health import Health
from companion.live.loops import CaptureLoop, FrameAdmission, InferenceLoop, LiveCounters, is_skipped
from companion.live.notify import Notifier
from companion.live.queues import DropOldestQueue
from companion.live.quiet_notice import QuietNotice
from companion.live.raw_gate import RawGate
from companion.live.resume_features import refresh_features
from companion.live.summary_keeper import SummaryKeeper
from companion.live.watchdog import Watchdog
from companion.sources.factory import open_source
from companion.sources.retrying import RetryingSource
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.storage.params_file import ParamsFile
from companion.storage.queries_file import QueriesFile
from companion.storage.store import ResumeState, Store, refuse_newer
from companion.storage.store_lock import StoreLock
from companion.vision.encoders.counted import CountedEncoder
from companion.vision.encoders.factory import make_encoder
from companion.vision.encoders.query_words import UnknownWord
from companion.vision.enhancers.factory import make_enhancer
from companion.vision.events import SummaryEvent, SummaryFrame
from companion.vision.gate import FrameGate
from companion.vision.pipeline import Pipeline
from companion.vision.topics import TopicSpec
from vehicle.autopilot.telemetry import VehicleTelemetry
from vehicle.camera import status as st
from vehicle.camera.downlink import Downlink
from vehicle.link.budget import Priority
from vehicle.link.connection import MavLink

log = logging.getLogger(__name__)

LIVE_PREFIXES = ("/dev/video", "/dev/v4l/", "v4l2://", "rtsp://", "rtsps://", "udp://")
CAPTURE_QUEUE = 4
"""Frames waiting to be encoded; beyond this the oldest is dropped (at 5 fps: under a second of backlog)."""
SKIPPED_QUEUE = 512
"""Frames the gate skipped waiting for the inference thread to count them (no pixels: ~8 s at 60 fps)."""


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
    store_lock: StoreLock | None = None
    """The store's lock, taken already by the caller (the demo, before it moves an earlier run aside), who also
    releases it; None: the companion takes it at start and releases it at stop."""


class LiveCompanion:
    """Wiring and start/stop order; what the surface asks is handled in ``companion.live.control``."""

    def __init__(self, cfg: Config, options: LiveOptions | None = None) -> None:
        self.cfg = cfg
        self.options = options or LiveOptions()
        self.notifier = self.options.notifier or Notifier(None)
        self.health = Health(cfg.health.stall_after_s)
        self.counters = LiveCounters()
        self.stop_event = threading.Event()
        self.queue = DropOldestQueue(CAPTURE_QUEUE, light=is_skipped, light_max=SKIPPED_QUEUE)
        self.started_at = time.monotonic()
        self.store_lock = self.options.store_lock or StoreLock(cfg.store.dir)
        self.store: Store | None = None
        self.keeper: SummaryKeeper | None = None
        self.saved_params: dict[str, float] = {}
        self.pipeline: Pipeline | None = None
        self.encoder: CountedEncoder | None = None
        self.control: ControlContext | None = None
        self.on_param: ParamHandler | None = None
        self.on_queries: QueriesHandler | None = None
        self.on_marks: MarksHandler | None = None
        self.on_shutter: ShutterHandler | None = None
        self.link: MavLink | None = None
        self.telemetry: VehicleTelemetry | None = None
        self.surface: Downlink | None = None
        self._quiet = QuietNotice(cfg.queries.below_threshold_after_s)
        self.source: RetryingSource | None = None
        self.capture: CaptureLoop | None = None
        self.inference: InferenceLoop | None = None
        self.selective: SelectiveStage | None = None
        self.enhance_worker: EnhanceWorker | None = None
        self._used_up_said = False
        self.watchdog = Watchdog(self.health, self.notifier, self.stop_event, self._update_status)

    @property
    def marks(self) -> SavedMarks:
        """The operator's marks in force (image indices), and the queries they were given under."""
        return self.on_marks.marks if self.on_marks is not None else SavedMarks()

    # ---- start-up -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        # a settings file from a newer version stops the start before anything is opened or written
        self.saved_params = self._params_file().load()
        refuse_newer(Path(self.cfg.store.dir))
        if not self.store_lock.held:
            self.store_lock.acquire()  # another live process on this store: stop here, exit 2, nothing touched
        self.store = Store(self.cfg.store, guard=self.store_lock.check)  # a folder swapped under it: stops writing
        queries_file = QueriesFile(self.store.dir / "queries.json", version=__version__, guard=self.store_lock.check)
        own = self.cfg
        self.cfg, configured = follow_saved_queries(own, queries_file)
        marks_file = MarksFile(self.store.dir / "marks.json", version=__version__, guard=self.store_lock.check)
        saved_marks = marks_file.load()
        resume = self.store.resume_state()
        if resume.frames:
            log.info("resuming with %d summary frame(s); next image index %d", len(resume.frames),
                     resume.next_image_index)
        try:
            self._build_pipeline(resume)
        except UnknownWord as err:
            if self.cfg is own:
                raise
            # an upload this encoder cannot read (made under another one, say) must not stop every restart
            log.warning("%s: saved queries not followed, following the configuration: %s", queries_file.path, err)
            self.cfg = own
            self._build_pipeline(resume)
        cfg = self.cfg
        self.keeper.start()  # from here on, what the surface asks is applied by the keeper's thread
        ctx = self.control = ControlContext(cfg, self.pipeline, self.keeper, self.encoder, self.store,
                                            self.selective)
        self.on_marks = MarksHandler(ctx, marks_file)
        self.on_queries = QueriesHandler(ctx, queries_file, configured, self.on_marks)
        self.on_param = ParamHandler(ctx)
        self.on_marks.restore(saved_marks)
        self._start_vehicle(resume.next_image_index)
        self._start_loops()
        self.watchdog.start()
        self.notifier.ready(self.status_line())
        log.info("companion running: source %s, encoder %s, mavlink %s, store %s", cfg.source.uri,
                 getattr(self.encoder, "name", "?"), cfg.mavlink.connection, self.store.dir)

    def _build_pipeline(self, resume: ResumeState) -> None:
        factory = self.options.make_encoder or make_encoder
        if self.encoder is None:  # built once, also when the saved queries are given up for the configured ones
            self.encoder = CountedEncoder(factory(self.cfg.encoder))  # counted: one pass serves every topic
        cfg = self.cfg
        if cfg.enhance.mode == "selective":
            # the pipeline samples enhanced frames behind a tau_ses gate; tau_ss is applied before the worker
            data = cfg.model_dump()
            data["enhance"]["mode"] = "none"
            data["queries"]["tau_ss"] = cfg.enhance.tau_ses
            for topic in data["queries"]["topics"]:
                topic["tau_ss"] = None  # a topic's own tau_ss is its raw gate's; enhanced frames face tau_ses
            data["gate"]["mode"] = "none"  # candidates arrive sparse and already chosen: never skip one
            self.pipeline = Pipeline.from_config(build_config(data, origin="enhance"), self.encoder,
                                                 first_image_index=resume.next_image_index)
            self.keeper = self._make_keeper()
            raw = RawGate(self.encoder, [TopicSpec.from_config(t) for t in cfg.queries.topic_list()],
                          cfg.queries.tau_ss)
            enhancer = make_enhancer(cfg.enhance, device=cfg.encoder.device)
            # ahead of the raw scoring
            gate = FrameGate(cfg.gate.mode, cfg.gate.threshold, cfg.gate.max_gap_s, cfg.gate.max_gap_share)
            self.selective = SelectiveStage(self.pipeline, raw, enhancer, queue_size=cfg.enhance.queue,
                                            lock=self.keeper.lock, gate=gate)
        else:
            self.pipeline = Pipeline.from_config(cfg, self.encoder, first_image_index=resume.next_image_index)
            self.keeper = self._make_keeper()

        def restore() -> list[SummaryEvent]:
            # features another encoder made are made again by this one first (the store keeps the new ones)
            frames = refresh_features(resume, self.encoder, self.pipeline.prepare, self.store).frames
            removed = self.pipeline.restore(frames)  # a smaller K than before the restart trims at once
            self.pipeline.next_image_index = max(self.pipeline.next_image_index, resume.next_image_index)
            return removed

        removed = self.keeper.change(restore)
        if resume.frames:  # which topic got which frame back, and what a topic no longer followed lost
            log.info("resumed topics: %s", "; ".join(f"{t.name} {[f.image_index for f in t.summary]}"
                                                      for t in self.pipeline.topics))
            dropped = sorted({e.frame.topic for e in removed} - {t.name for t in self.pipeline.topics})
            if dropped:
                log.warning("frames of topic(s) %s left the summary: not in the queries in force",
                            ", ".join(dropped))

    def _make_keeper(self) -> SummaryKeeper:
        def tags(frame: SummaryFrame) -> dict[str, Any]:
            topic = next((t for t in self.pipeline.topics if t.name == frame.topic), self.pipeline.topics[0])
            presampler = topic.presampler
            return {"query": presampler.positive,  # the topic's live query, which the surface may change
                    "tau_ss": presampler.tau_ss,  # the threshold its score is read against (exports flag below)
                    "encoder": getattr(self.encoder, "name", ""), "source": self.cfg.source.uri}

        return SummaryKeeper(self.pipeline, self.store, tags=tags, publish=self._publish)

    def _publish(self, event: SummaryEvent) -> None:
        if self.surface is not None:
            if self.store.dive != self.surface.dive:
                self._new_dive()
            self.surface.publish(event)
            self._tell_quiet(event)

    def _new_dive(self) -> None:
        """The store could not persist its next image index and took a new dive id (``DiveIndex``): announce under
        it from this frame on, and tell the surface (the store has logged why)."""
        self.surface.set_dive(self.store.dive)
        self.surface.event(f"Index not saved: new dive id {self.store.dive}", st.WARNING)

    def _tell_quiet(self, event: SummaryEvent) -> None:
        """A topic's first stand-in (nothing passed for a while): say so once, as a warning the page shows."""
        line = self._quiet.line_for(event)
        if line is not None:
            self.surface.event(line, st.WARNING)

    def _params_file(self) -> ParamsFile:
        if self.options.params_path:
            return ParamsFile(self.options.params_path, version=__version__)
        return ParamsFile(Path(self.cfg.store.dir) / "params.json", version=__version__, guard=self.store_lock.check)

    def _start_vehicle(self, image_count: int) -> None:
        cfg = self.cfg
        if not cfg.mavlink.connection:
            log.warning("mavlink.connection is null: no vehicle link, no surface link (store only)")
            return
        self.link = MavLink(cfg.mavlink.connection, cfg.mavlink, name="companion")
        self.link.healthy = self.health.healthy
        self.telemetry = VehicleTelemetry(self.link, cfg.telemetry)
        specs = default_params(cfg)
        defaults = {spec.name: spec.value for spec in specs}  # before the saved values are applied to the specs
        self.surface = Downlink(
            self.link, cfg.surface, params=specs, saved_params=self.saved_params,
            persist_params=self._params_file().save,
            loader=self.store.frame, image_count=image_count, stored_jpeg=self.store.frame_jpeg,
            queries=self.on_queries.topics(), default_topic=cfg.queries.name, version=__version__,
            dive=self.store.dive,
        )
        self.control.surface = self.surface
        self.surface.on_param_changed(self.on_param, replay=False)
        # what the operator set last time; a value refused now is served and saved as what is in force
        self.on_param.restore(self.surface.params.restored, lambda name: self.surface.params.set(name, defaults[name]))
        self.telemetry.on_notice(self.surface.event)  # e.g. "no position source", once, as a STATUSTEXT
        self.link.on_signing_change(self.surface.event)  # the autopilot's signing changed, once per change
        self.store.on_health(self._on_store_health)  # a full or read-only store, and its recovery, reach the surface
        if self.store.memory_only:
            self._on_store_health(True, self.store.memory_only_reason)
        self.surface.on_queries_changed(self.on_queries)
        self.surface.on_marks_changed(self.on_marks)
        self.on_shutter = ShutterHandler(self.control, lambda: self.capture.latest if self.capture else None,
                                         self._pose_at)
        self.surface.camera.shutter.wire(self.on_shutter)  # from now on CAMERA_INFORMATION offers a shutter
        self.surface.camera.storage = self.store.space  # STORAGE_INFORMATION and the capture status read it
        self.surface.set_marks(self.marks.like, self.marks.unlike)
        serve_keeper_document(self.control, self.on_marks)
        self.link.on_autopilot(AutopilotNotice(self.control))
        self.link.start()
        self.telemetry.start()
        self.surface.start()
        self.keeper.republish()  # the resumed summary is on the FTP tree again

    def _on_store_health(self, memory_only: bool, reason: str) -> None:
        """The store left the disk (a WARNING, once) or came back to it (INFO): one STATUSTEXT each."""
        if memory_only:
            self.surface.event(f"Store {reason}: kept in memory", st.WARNING)
        else:
            self.surface.event("Store writable again: back on disk", st.INFO)

    def _start_loops(self) -> None:
        cfg = self.cfg.source
        self.source = RetryingSource(
            lambda: open_source(cfg), name=cfg.uri, live=is_live_uri(cfg.uri), loop=False,
            initial_s=cfg.retry_initial_s, max_s=cfg.retry_max_s, on_state=lambda state, _detail: source_notice(self.control, self.source, state),
            beat=lambda: self.health.beat("capture"),
        )
        admission = FrameAdmission(self.pipeline.prepare, lambda: self.control.frame_gate, self.pipeline.encode_size)
        self.capture = CaptureLoop(self.source, self.queue, self.health, self.counters, self.stop_event, admission)
        self.inference = InferenceLoop(
            self.pipeline, self.queue, self.health, self.counters, self.stop_event,
            batch=self.cfg.encoder.batch, pose_at=self._pose_at, keeper=self.keeper, selective=self.selective,
        )
        if self.selective is not None:
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

    # ---- health, status -----------------------------------------------------------------------------------------
    def _update_status(self) -> None:
        if self.store is not None:
            self.store.retry()  # a memory-only store tries the disk again (every few seconds)
        depth = None
        if self.telemetry is not None:
            pose = self._pose_at(time.time())
            depth = getattr(pose, "depth_m", None) if pose is not None and not pose.stale else None
        if self.surface is not None:
            self.surface.update_status(fps=self.counters.fps(), seen_fps=self.counters.seen_fps(), score=self.counters.last_score,
                                       summary=len(self.store.summary), depth_m=depth)
        self._say_indices_used_up()
        self.notifier.status(self.status_line())

    def _say_indices_used_up(self) -> None:
        """Once, as a WARNING (the vehicle rides through it; the summary held is still served): every image index
        MAVLink carries was handed out (the pipeline and the store log it as an error), so nothing new enters the
        summary until the store is moved aside."""
        if self._used_up_said or self.pipeline is None or not self.pipeline.indices_used_up:
            return
        if self.surface is not None:
            self._used_up_said = True
            self.surface.event("Image indices used up: start a new store", st.WARNING)

    def status_line(self) -> str:
        c = self.counters
        src = self.source.state if self.source is not None else "starting"
        ap = "up" if self.link is not None and self.link.autopilot_alive else "down"
        store = (f"memory-only ({self.store.memory_only_reason})" if self.store is not None and self.store.memory_only
                 else "ok")
        return (f"source {src}; {c.rates_text()}; seen {c.frames_seen} passed {c.frames_passed}; "
                f"summary {self._summary_text()}; dropped {self.queue.dropped}; autopilot {ap}; store {store}")

    def _summary_text(self) -> str:
        """"3/6" with one topic; "fish 3/6, coral 2/6" with several (the keeper's counts after its last change)."""
        k = self.pipeline.sampler.k if self.pipeline is not None else self.cfg.sampler.k  # MERL_K may change it
        held = self.keeper.held_by_topic() if self.keeper is not None else {}
        used_up = " (image indices used up)" if self.pipeline is not None and self.pipeline.indices_used_up else ""
        if len(held) > 1:
            return ", ".join(f"{name} {n}/{k}" for name, n in held.items()) + used_up
        summary = len(self.store.summary) if self.store is not None else 0
        duplicates = self.pipeline.counts["duplicates"] if self.pipeline is not None else 0
        # a summary short of K with duplicates refused: the dive has no more distinct views (issue 25)
        return f"{summary}/{k}" + (f" ({duplicates} duplicates not kept)" if duplicates else "") + used_up

    def keeper_document(self) -> dict[str, Any]:
        """/store/summary.json (companion.live.control.summary_file)."""
        return keeper_document(self.control, self.on_marks)

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
            "topics": self._topics_report(),
            "images_encoded": getattr(self.encoder, "images", 0),
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
            "watchdog_pings": self.watchdog.pings, "watchdog_withheld": self.watchdog.withheld,
            "uptime_s": round(time.monotonic() - self.started_at, 1),
        }

    def _topics_report(self) -> dict[str, dict[str, Any]]:
        """Each topic followed: its positive query and the image indices its summary holds."""
        if self.pipeline is None or self.keeper is None:
            return {}
        with self.keeper.lock:
            return {t.name: {"positive": t.presampler.positive, "summary": [f.image_index for f in t.summary]}
                    for t in self.pipeline.topics}

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
        for thread in (self.capture, self.inference, self.enhance_worker, self.watchdog):
            if thread is not None and thread.is_alive():
                thread.join(timeout=15)

    def drain(self, timeout: float) -> bool:
        """Wait (at most ``timeout``) until the thumbnails already queued for the surface are on the wire."""
        if self.surface is None:
            return True
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
        if self.keeper is not None:
            self.keeper.stop()  # after the surface link: a request it is answering gets its change applied
        if self.telemetry is not None:
            self.telemetry.stop()
        if self.link is not None:
            self.link.stop()
        if self.options.store_lock is None:
            self.store_lock.release()  # after the keeper: its last change is on disk
        self.notifier.close()

