"""The topics the surface uploads (/config/queries.txt): checked, applied between two batches, saved, followed
again after a restart unless the configuration changed since."""

from __future__ import annotations

import logging

from companion.config import Config, ConfigError, build_config
from companion.errors import MerlionError
from companion.live.control.context import ControlContext
from companion.live.control.marks import MarksHandler
from companion.live.control.query_answer import refusal_line, resolution_lines
from companion.storage.queries_file import QueriesFile, SavedQueries, topic_dicts
from companion.vision.events import SummaryEvent
from companion.vision.presampler import GENERIC_NEGATIVE
from companion.vision.topics import TopicSpec
from vehicle.camera import status as st
from vehicle.protocol.queries import QueryTopic

log = logging.getLogger(__name__)


def follow_saved_queries(cfg: Config, file: QueriesFile) -> tuple[Config, list[dict]]:
    """``cfg`` with the topics the surface uploaded before a restart, unless the configuration changed since;
    and the configured topics as a saved upload records them (never the uploaded ones)."""
    configured = topic_dicts(cfg.queries.topic_list())
    saved = file.load()
    if saved is None:
        return cfg, configured
    if saved.configured != configured:
        log.warning("%s: the configuration's topics changed since that upload: following the configuration",
                    file.path)
        return cfg, configured
    own_tau = {t.name: t.tau_ss for t in cfg.queries.topic_list()}
    data = cfg.model_dump()
    data["queries"]["topics"] = [{**t, "tau_ss": own_tau.get(t["name"])} for t in saved.topics]
    try:
        followed = build_config(data, origin=str(file.path))
    except ConfigError as err:
        log.warning("saved queries not followed: %s", err)
        return cfg, configured
    log.info("following the topics uploaded before the restart (%s): %s", file.path,
             ", ".join(t["name"] for t in saved.topics))
    return followed, configured


class QueriesHandler:
    """``Downlink.on_queries_changed``'s callback: the topics to follow from the next batch on (a topic no longer
    listed leaves the summary; a kept one keeps its frames under its new queries); ValueError refuses the file."""

    def __init__(self, ctx: ControlContext, file: QueriesFile, configured: list[dict], marks: MarksHandler) -> None:
        self.ctx = ctx
        self.file = file
        self.configured = configured
        """The configured topics, saved beside an upload (a later configuration change wins over the upload)."""
        self.marks = marks

    def topics(self) -> list[QueryTopic]:
        """The topics in force as the queries file states them."""
        return [QueryTopic(t.name, t.presampler.positive, tuple(t.presampler.negatives))
                for t in self.ctx.pipeline.topics]

    def __call__(self, topics: list[QueryTopic]) -> None:
        ctx = self.ctx
        specs = [TopicSpec(t.name, t.positive, tuple(t.negatives)) for t in topics]
        # all or nothing, before the keeper's turn: a query the encoder cannot score refuses the file with no
        # topic changed, and a CLIP text not yet cached is encoded now (a child process, seconds) rather than
        # while the inference loop waits; in the change the texts are then in memory
        self.check(specs)
        self.say_resolved(specs)

        def set_topics() -> list[SummaryEvent]:
            # the raw gate first: its pre-samplers score the pipeline's topics (``OuterDive``), so it must follow
            # every topic the pipeline does, also if the pipeline's change were refused
            if ctx.selective is not None:
                ctx.selective.raw.set_topics(specs)
            events = ctx.pipeline.set_topics(specs)
            if ctx.selective is not None:
                ctx.selective.sync_gates()
            return events

        ctx.keeper.submit(set_topics)
        try:  # a restart goes on with these topics (and the frames they hold)
            self.file.save(SavedQueries(topic_dicts(specs), self.configured))
        except OSError as err:  # a memory-only store: they hold for this run
            log.warning("queries not saved: %s", err)
        if len(specs) == 1:
            log.info("queries set: %r against %r", specs[0].positive, list(specs[0].negatives))
        else:
            log.info("topics set: %s", ", ".join(f"{s.name}={s.positive!r}" for s in specs))
        if self.marks.marks:  # marks teach what this query should find: a new query starts untaught
            self.marks([], [])
            log.info("marks cleared with the queries")
            ctx.say("Marks cleared with the queries")

    def check(self, specs: list[TopicSpec]) -> None:
        """Refuse (ValueError, and why on the surface) queries the encoder cannot score, e.g. a concept the
        packaged encoder does not know, before any topic changes."""
        encoder = self.ctx.encoder
        for spec in specs:
            try:
                encoder.encode_texts([spec.positive, *spec.negatives])
                if not [n for n in spec.negatives if n.strip()]:
                    try:  # the pre-sampler's own negative then: embedded now too, if the encoder can
                        encoder.encode_texts([GENERIC_NEGATIVE])
                    except MerlionError:
                        pass  # the packaged encoder scores the positive alone
            except MerlionError as err:
                self.ctx.say(refusal_line(spec.name, err), st.WARNING)
                raise ValueError(f"topic {spec.name}: {err}") from None

    def say_resolved(self, specs: list[TopicSpec]) -> None:
        """Tell the surface what each query was read as (the packaged encoder's WordNet classes)."""
        for line in resolution_lines(self.ctx.encoder, [(s.name, [s.positive, *s.negatives]) for s in specs]):
            self.ctx.say(line)
