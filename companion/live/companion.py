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
from companion.config import Config, ConfigError, build_config
from companion.live.health import Health
from companion.live.loops import CaptureLoop, InferenceLoop, LiveCounters
from companion.live.notify import Notifier
from companion.live.queues import DropOldestQueue
from companion.live.summary_keeper import SummaryKeeper
from companion.sources.frame import Frame
from companion.sources.retrying import RetryingSource
from companion.storage.marks_file import MarksFile, SavedMarks
from companion.storage.params_file import ParamsFile
from companion.storage.queries_file import QueriesFile, SavedQueries, topic_dicts
from companion.storage.store import Store
from companion.vision.events import SummaryEvent, SummaryFrame

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
        self._configured: list[dict[str, Any]] = []
        self.marks = SavedMarks()
        """The operator's marks in force (image indices), and the queries they were given under."""
        self.mark_images = 0
        """Marked frames the encoder embedded (beside the frames it scored)."""
        self.pipeline = None
        self.encoder = None
        self.link = None
        self.telemetry = None
        self.surface = None
        self._autopilot_seen = False
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
        self._follow_saved_queries()
        cfg = self.cfg
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
        from companion.vision.encoders.counted import CountedEncoder

        self.encoder = CountedEncoder(factory(self.cfg.encoder))  # counted: one pass serves every topic
        cfg = self.cfg
        if cfg.enhance.mode == "selective":
            # the pipeline samples enhanced frames behind a tau_ses gate; tau_ss is applied before the worker
            from companion.live.enhance_worker import SelectiveStage
            from companion.live.raw_gate import RawGate
            from companion.vision.enhancers.factory import make_enhancer
            from companion.vision.topics import TopicSpec

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
            from companion.vision.gate import FrameGate

            gate = FrameGate(cfg.gate.mode, cfg.gate.threshold, cfg.gate.max_gap_s)  # ahead of the raw scoring
            self.selective = SelectiveStage(self.pipeline, raw, enhancer, queue_size=cfg.enhance.queue,
                                            lock=self.keeper.lock, gate=gate)
        else:
            self.pipeline = Pipeline.from_config(cfg, self.encoder, first_image_index=resume.next_image_index)
            self.keeper = self._make_keeper()

        def restore() -> list[SummaryEvent]:
            removed = self.pipeline.restore(resume.frames)  # a smaller K than before the restart trims at once
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

    def _queries_file(self) -> QueriesFile:
        return QueriesFile(self.store.dir / "queries.json", version=__version__)

    def _follow_saved_queries(self) -> None:
        """Take up the topics the surface uploaded before a restart, unless the configuration changed since."""
        self._configured = topic_dicts(self.cfg.queries.topic_list())
        """The configured topics, as the saved upload records them (never the uploaded ones)."""
        path = self._queries_file().path
        saved = self._queries_file().load()
        if saved is None:
            return
        if saved.configured != self._configured:
            log.warning("%s: the configuration's topics changed since that upload: following the configuration",
                        path)
            return
        own_tau = {t.name: t.tau_ss for t in self.cfg.queries.topic_list()}
        data = self.cfg.model_dump()
        data["queries"]["topics"] = [{**t, "tau_ss": own_tau.get(t["name"])} for t in saved.topics]
        try:
            self.cfg = build_config(data, origin=str(path))
        except ConfigError as err:
            log.warning("saved queries not followed: %s", err)
            return
        log.info("following the topics uploaded before the restart (%s): %s", path,
                 ", ".join(t["name"] for t in saved.topics))

    def _make_keeper(self) -> SummaryKeeper:
        def tags(frame: SummaryFrame) -> dict[str, Any]:
            topic = next((t for t in self.pipeline.topics if t.name == frame.topic), self.pipeline.topics[0])
            presampler = topic.presampler
            return {"query": presampler.positive,  # the topic's live query, which the surface may change
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
            queries=self._query_topics(), default_topic=cfg.queries.name, version=__version__,
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
        self.surface.tree.put(KEEPER_PATH, lambda: json.dumps(self.keeper_document()).encode())
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
        if name in ("MERL_TAU_SS", "MERL_TAU_SES", "MERL_K", "MERL_ENHANCE", "MERL_GATE"):
            self.keeper.change(lambda: self._tune(name, value))
            log.info("parameter %s set to %g", name, value)

    def _tune(self, name: str, value: float) -> list[SummaryEvent]:
        """Runs inside the keeper: the pipeline changes and the trims it causes reach the store together."""
        sel = self.selective
        if name == "MERL_TAU_SS":
            if sel is not None:
                sel.raw.tau_ss = value  # every topic's raw gate
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
            gate = sel.gate if sel is not None else self.pipeline.gate  # selective: the gate before raw scoring
            gate.mode = "difference" if value > 0 else "none"
            gate.threshold = max(0.0, float(value))
        elif name == "MERL_ENHANCE":
            if sel is not None:
                sel.on = bool(value)
                self._selective_gates()
            else:  # enhance.mode always: every frame enhanced, or none
                self.pipeline.enhance_mode = "always" if value else "none"
        return []

    def _selective_gates(self) -> None:
        """enhance.mode selective: the pipeline's gate is tau_ses while the enhancer runs, else each topic's own
        tau_ss (the raw gate's), so switching MERL_ENHANCE off leaves every topic its threshold."""
        sel = self.selective
        for topic in self.pipeline.topics:
            topic.presampler.tau_ss = self.pipeline.tau_ses if sel.on else sel.raw.tau_of(topic.name)

    def _refuse(self, name: str, why: str, detail: str = "") -> None:
        """Say on the surface why a parameter change is refused (``why``, short), then refuse it with ``detail``
        for the log (the value stays as it was)."""
        if self.surface is not None:
            from vehicle.camera import status as st

            self.surface.event(f"{name} refused: {why}"[:50], st.WARNING)
        raise ValueError(detail or why)

    def _check_enhance(self, on: bool) -> None:
        """MERL_ENHANCE=1 needs an enhancer, loaded at start only when enhance.mode asks for one: refuse, and
        say why on the surface, rather than accept a value that changes nothing."""
        if on and self.cfg.enhance.mode == "none":
            self._refuse("MERL_ENHANCE", "enhance.mode is none", "enhance.mode is none (no enhancer loaded); set "
                         "enhance.mode: selective or always and restart")

    def _query_topics(self) -> list:
        """The topics in force as the queries file states them."""
        from vehicle.protocol.queries import QueryTopic

        return [QueryTopic(t.name, t.presampler.positive, tuple(t.presampler.negatives))
                for t in self.pipeline.topics]

    def _on_queries(self, topics: list) -> None:
        """A queries file from the surface: the topics to follow from the next batch on (a topic no longer listed
        leaves the summary; a kept one keeps its frames under its new queries)."""
        from companion.vision.topics import TopicSpec

        specs = [TopicSpec(t.name, t.positive, tuple(t.negatives)) for t in topics]
        # all or nothing, before the keeper's lock: a query the encoder cannot score refuses the file with no
        # topic changed, and a CLIP text not yet cached is encoded now (a child process, seconds) rather than
        # while the inference loop waits; under the lock the texts are then in memory
        self._check_queries(specs)

        def set_topics() -> list[SummaryEvent]:
            events = self.pipeline.set_topics(specs)
            if self.selective is not None:  # the raw gate follows every topic, kept, new or dropped
                self.selective.raw.set_topics(specs)
                self._selective_gates()
            return events

        self.keeper.change(set_topics)
        try:  # a restart goes on with these topics (and the frames they hold)
            self._queries_file().save(SavedQueries(topic_dicts(specs), self._configured))
        except OSError as err:  # a memory-only store: they hold for this run
            log.warning("queries not saved: %s", err)
        if len(specs) == 1:
            log.info("queries set: %r against %r", specs[0].positive, list(specs[0].negatives))
        else:
            log.info("topics set: %s", ", ".join(f"{s.name}={s.positive!r}" for s in specs))
        if self.marks:  # marks teach what this query should find: a new query starts untaught
            self._on_marks([], [])
            log.info("marks cleared with the queries")
            if self.surface is not None:
                self.surface.event("Marks cleared with the queries")

    def _check_queries(self, specs) -> None:
        """Refuse (ValueError, and why on the surface) queries the encoder cannot score, e.g. a concept the
        packaged encoder does not know, before any topic changes."""
        from companion.errors import MerlionError
        from companion.vision.presampler import GENERIC_NEGATIVE

        for spec in specs:
            try:
                self.encoder.encode_texts([spec.positive, *spec.negatives])
                if not [n for n in spec.negatives if n.strip()]:
                    try:  # the pre-sampler's own negative then: embedded now too, if the encoder can
                        self.encoder.encode_texts([GENERIC_NEGATIVE])
                    except MerlionError:
                        pass  # the packaged encoder scores the positive alone
            except MerlionError as err:
                if self.surface is not None:
                    from vehicle.camera import status as st

                    self.surface.event(f"Queries refused: {spec.name}: {err}"[:50], st.WARNING)
                raise ValueError(f"topic {spec.name}: {err}") from None

    # ---- the operator's marks -----------------------------------------------------------------------------------
    def _on_marks(self, like: list[int], unlike: list[int]) -> None:
        """Marks from the surface (image indices): score by them from the next batch on, and keep them on disk.

        ValueError (a frame the store no longer has) refuses the upload; the surface gets a NAK.
        """
        self._apply_marks(like, unlike)
        self.marks = SavedMarks(list(like), list(unlike), self.pipeline.presampler.positive,
                                {t.name: t.presampler.positive for t in self.pipeline.topics})
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
        """Re-apply the marks an earlier run saved, each only if its topic's query is still the one in force."""
        if not saved:
            return
        queries = {t.name: t.presampler.positive for t in self.pipeline.topics}

        def current(indices: list[int]) -> list[int]:
            kept = []
            for index in indices:
                topic = self._topic_of(index)
                if topic is None or saved.query_of(topic) == queries.get(topic):
                    kept.append(index)  # (a frame the store lacks: refused below, naming it)
                else:
                    log.info("saved marks were given for %r, not %r: not applied to image %d (topic %s)",
                             saved.query_of(topic), queries.get(topic), index, topic)
            return kept

        like, unlike = current(saved.like), current(saved.unlike)
        if not like and not unlike:
            return
        try:
            self._apply_marks(like, unlike)
        except ValueError as err:
            log.warning("saved marks not applied: %s", err)
            return
        self.marks = SavedMarks(like, unlike, saved.query, {t: q for t, q in saved.topics.items() if t in queries})
        log.info("restored marks: %d like, %d unlike", len(like), len(unlike))

    def _topic_of(self, index: int) -> str | None:
        """The topic a summary frame belongs to: the one holding it, else its sidecar's (a frame stored before
        topics: the default topic, ``queries.name``); None when the store does not have it."""
        held = self.pipeline.topic_of(index)
        if held is not None:
            return held.name
        sidecar = self.store.sidecar(index)
        if sidecar is None:
            return None
        return str(sidecar.get("topic") or self.pipeline.untagged_topic())

    def _apply_marks(self, like: list[int], unlike: list[int]) -> None:
        """Embed the marked frames' stored images and switch each topic's pre-sampler(s) to the combined score.

        A mark teaches the topic of the frame it names (marking a coral frame says nothing about fish), so each
        topic gets only its own marks, and a topic with none scores by its queries alone. Runs inside the
        keeper: the encoder is the inference loop's, and the next batch sees the new scores.
        """
        from companion.vision.feedback import Marks

        def images(indices: list[int]) -> dict[str, list]:
            found: dict[str, list] = {t.name: [] for t in self.pipeline.topics}
            for index in indices:
                frame = self.store.frame(index)
                if frame is None or frame.image is None:
                    raise ValueError(f"image {index} is not in the store")
                topic = self._topic_of(index)
                if topic not in found:
                    raise ValueError(f"image {index} is of topic {topic}, no longer followed")
                found[topic].append(self.pipeline.prepare(frame.image))
            return found

        def apply() -> None:
            liked, unliked = images(like), images(unlike)  # all checked before any topic changes
            for topic in self.pipeline.topics:
                if liked[topic.name] or unliked[topic.name]:
                    marks = Marks.from_images(self.encoder, liked[topic.name], unliked[topic.name])
                    self.mark_images += len(liked[topic.name]) + len(unliked[topic.name])
                else:
                    marks = Marks(np.zeros((0, 1)), np.zeros((0, 1)))
                topic.presampler = _marked(topic.presampler, marks)
                if self.selective is not None:
                    raw = self.selective.raw.presamplers
                    raw[topic.name] = _marked(raw[topic.name], marks)

        self.keeper.change(apply)

    def _on_autopilot(self, alive: bool) -> None:
        first = alive and not self._autopilot_seen  # the first contact is "up"; only after a loss is it "back"
        self._autopilot_seen = self._autopilot_seen or alive
        if first:
            log.info("autopilot heartbeat up")
        elif alive:
            log.info("autopilot heartbeat back")
        else:
            log.warning("autopilot heartbeat lost; frames are tagged stale until it returns")
        if self.surface is not None:
            from vehicle.camera import status as st

            self.surface.event(*st.link_text(alive, first))

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
        return (f"source {src}; {c.fps():.1f} fps; seen {c.frames_seen} passed {c.frames_passed}; "
                f"summary {self._summary_text()}; dropped {self.queue.dropped}; autopilot {ap}; store {store}")

    def _summary_text(self) -> str:
        """"3/6" with one topic; "fish 3/6, coral 2/6" with several (the keeper's counts after its last change)."""
        k = self.pipeline.sampler.k if self.pipeline is not None else self.cfg.sampler.k  # MERL_K may change it
        held = self.keeper.held_by_topic() if self.keeper is not None else {}
        if len(held) > 1:
            return ", ".join(f"{name} {n}/{k}" for name, n in held.items())
        summary = len(self.store.summary) if self.store is not None else 0
        duplicates = self.pipeline.counts["duplicates"] if self.pipeline is not None else 0
        # a summary short of K with duplicates refused: the dive has no more distinct views (issue 25)
        return f"{summary}/{k}" + (f" ({duplicates} duplicates not kept)" if duplicates else "")

    def keeper_document(self) -> dict[str, Any]:
        """/store/summary.json: the keeper's summary and history, each frame's topic, and what the encoder did,
        all read under the keeper's lock (so the counts belong to the same moment as the summary).

        ``encoder.images`` counts what the encoder itself was given; ``scored`` the images whose scores were
        computed (each frame once, and with enhance.mode selective each enhanced version once more) and
        ``marks`` the marked frames embedded. ``images == scored + marks`` however many topics are followed: one
        encoder pass serves them all.
        """
        with self.keeper.lock:
            doc = self.keeper.document()
            doc["topics"] = {t.name: [f.image_index for f in t.summary] for t in self.pipeline.topics}
            scored = self.pipeline.counts["encoded"] + (self.selective.scored if self.selective is not None else 0)
            doc["encoder"] = {"images": self.encoder.images, "calls": self.encoder.calls, "scored": scored,
                              "marks": self.mark_images}
        return doc

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
            "watchdog_pings": self.watchdog_pings, "watchdog_withheld": self.watchdog_withheld,
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
