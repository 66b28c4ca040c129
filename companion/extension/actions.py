"""What the widget's buttons and Cockpit's actions do: mark a frame (or the newest one), follow a preset topic,
start or stop the companion. Each is a web server action (JSON in, JSON out; a ValueError is a 400)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from companion.config import MavlinkConfig, TopicConfig
from companion.errors import MerlionError
from companion.topside.actions import page_mark
from companion.topside.queries_upload import queries_from_options, upload_queries
from companion.topside.tool import SurfaceTool
from companion.topside.web import Action

UPLOADER_SYSTEM, UPLOADER_COMPONENT = 254, 191
"""The topic switch's own connection: the surface tool's system, another component."""


MAX_QUERY = 200
"""The longest query the widget may send (the companion's queries file is small)."""
ASKED = "asked"
"""The topic name of a query typed on the widget or the page."""


def uploader(signing_key_file: str | None) -> MavlinkConfig:
    """The topic switch's connection, signing with the companion's key when it has one: a signing companion ignores
    unsigned FTP writes ("file protected")."""
    return MavlinkConfig(system_id=UPLOADER_SYSTEM, component_id=UPLOADER_COMPONENT, signing_key_file=signing_key_file)


class CompanionProcess(Protocol):
    @property
    def running(self) -> bool: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...


def extension_actions(tool: SurfaceTool, *, connect: str, topics: list[TopicConfig],
                      companion: CompanionProcess | None = None,
                      signing_key_file: str | None = None) -> dict[str, Action]:
    """``connect``: how the topic switch reaches the companion (the extension's hub); ``companion``: the process
    start/stop controls (None: not run by this extension, no such action); ``signing_key_file``: the companion's
    key, which the topic switch signs with."""
    sender = uploader(signing_key_file)
    presets = {t.name: t for t in topics}

    def mark(body: dict) -> dict:
        return page_mark(tool.actions, body.get("index"), body.get("kind"))

    def mark_newest(body: dict) -> dict:
        held = [f["image_index"] for f in tool.snapshot()["summary"]]
        if not held:
            raise ValueError("mark: no summary frame yet")
        return page_mark(tool.actions, max(held), body.get("kind"))

    def chosen_topic(body: dict) -> dict:
        """A preset (``{"topic": NAME}``) or the pilot's own words (``{"query": TEXT}``, with the first preset's
        negatives, under the name ``ASKED``)."""
        if "query" in body:
            text = body["query"]
            if not isinstance(text, str) or not text.strip() or len(text) > MAX_QUERY:
                raise ValueError(f"query {str(text)[:40]!r}: give the words to look for (1-{MAX_QUERY} characters)")
            if not topics or not topics[0].negatives:
                raise ValueError("query: the configuration has no negative query to go with it")
            return {"name": ASKED, "positive": " ".join(text.split()), "negatives": list(topics[0].negatives)}
        name = body.get("topic")
        if not isinstance(name, str) or name not in presets:
            raise ValueError(f"topic {str(name)[:40]!r}: not one of "
                             f"{', '.join(presets) or 'the configured topics (none)'}")
        return {"name": name, "positive": presets[name].positive, "negatives": list(presets[name].negatives)}

    def topic(body: dict) -> dict:
        """Follow the chosen topic alone; a refusal (a query the companion's encoder cannot read) is a 400 with the
        companion's reason, and the companion keeps its topics (it checks a file whole before changing any)."""
        chosen = chosen_topic(body)
        ident = tool.snapshot()["companion"]["id"]
        if not ident:
            raise ValueError("topic: no companion heard yet")
        try:
            data = queries_from_options(None, [], [chosen])
            answer = upload_queries(connect, sender, (ident[0], ident[1]), data, timeout=15.0)
        except MerlionError as err:
            raise ValueError(str(err)) from None
        if not answer.accepted:
            said = " ".join(answer.status)
            raise ValueError(f"topic {chosen['name']} ({chosen['positive']!r}) refused: {answer.error or ''} "
                             f"{said}".replace("  ", " ").strip())
        return {"topic": chosen["name"], "query": chosen["positive"], "status": answer.status}

    actions: dict[str, Callable[[dict], dict]] = {"mark": mark, "mark-newest": mark_newest, "topic": topic}
    if companion is not None:
        def run(body: dict) -> dict:
            wanted = body.get("run")
            if not isinstance(wanted, bool):
                raise ValueError(f"companion: run must be true or false, got {wanted!r}")
            if wanted:
                companion.start()
            else:
                companion.stop()
            return {"companion_running": companion.running}

        actions["companion"] = run
    return actions
