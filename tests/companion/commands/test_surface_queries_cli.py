"""``merlion surface-queries`` as a real subprocess uploading /config/queries.txt to a real companion.

The companion side is the real Downlink on a real UDP socket (its FTP server, its queries parser, its STATUSTEXT
answers); the command is checked for an accepted file (one topic and several), refusals (the vehicle's parser
and the app's own), no companion at all, and bad input that is refused before anything is sent. The last test
runs it end to end against a real `merlion run` and a real `merlion surface`.
"""

from __future__ import annotations

import pytest

from companion.config import SurfaceConfig
from companion.live.udp_hub import UdpHub
from tests.companion.live_harness import FAST_SOURCE, Companion, wait_until, write_config
from tests.companion.topside.live_page import page_state, surface_with_page
from tests.conftest import free_udp_port, run_merlion
from tests.vehicle.surface_env import companion_link
from vehicle.camera.downlink import QUERIES_PATH, Downlink
from vehicle.protocol.queries import QueryTopic

TWO_TOPICS = ("[fish]\nunderwater image with fish\nunderwater image without fish\n"
              "[coral]\nunderwater image of a coral reef\nunderwater image of sand\nunderwater image of rocks\n")


def _companion(default_topic: str = "main"):
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, push=False, ftp_writable=True),
                       queries=[QueryTopic(default_topic, "underwater image with fish", ("no fish",))],
                       default_topic=default_topic)
    changed: list[list[tuple[str, str, tuple[str, ...]]]] = []

    def on_queries(topics: list[QueryTopic]) -> None:
        if any("busy" in t.positive for t in topics):
            raise ValueError("the app refuses it")  # as the live companion may
        changed.append([(t.name, t.positive, t.negatives) for t in topics])

    surface.on_queries_changed(on_queries)
    surface.start()
    return port, link, surface, changed


@pytest.fixture
def companion():
    port, link, surface, changed = _companion()
    yield port, surface, changed
    surface.stop()
    link.stop()


def _upload(port: int, *args: str):
    return run_merlion("surface-queries", "--connect", f"udpout:127.0.0.1:{port}", "--timeout", "20", *args,
                       timeout=60)


def test_a_file_of_two_topics_is_set_and_the_companion_says_so(companion, tmp_path):
    port, surface, changed = companion
    queries = tmp_path / "queries.txt"
    queries.write_text(TWO_TOPICS)
    done = _upload(port, str(queries))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "merlion surface-queries: 1:100 says: Topics set: fish, coral"
    assert changed == [[("fish", "underwater image with fish", ("underwater image without fish",)),
                        ("coral", "underwater image of a coral reef",
                         ("underwater image of sand", "underwater image of rocks"))]]
    held = surface.tree.read(QUERIES_PATH).decode()
    assert "[fish]" in held and "[coral]" in held


def test_one_topic_from_the_command_line_and_several_with_topic(companion):
    port, surface, changed = companion
    done = _upload(port, "--query", "underwater image with a crab", "--negative", "underwater image of sand")
    assert done.returncode == 0, done.stderr
    assert "says: Queries set: underwater image with a crab" in done.stdout
    assert changed[-1] == [("main", "underwater image with a crab", ("underwater image of sand",))]
    done = _upload(port, "--topic", "crab=a crab;sand", "--topic", "ray=a ray;sand;rocks")
    assert done.returncode == 0, done.stderr
    assert "says: Topics set: crab, ray" in done.stdout
    assert changed[-1] == [("crab", "a crab", ("sand",)), ("ray", "a ray", ("sand", "rocks"))]


def test_a_file_the_companion_refuses_is_an_error_with_its_reason(tmp_path):
    # a simple-form topic before [fish] lines: fine here, but this vehicle names its default topic "fish" too
    port, link, surface, changed = _companion(default_topic="fish")
    try:
        queries = tmp_path / "queries.txt"
        queries.write_text("a crab\nsand\n[fish]\nfish\nno fish\n")
        done = _upload(port, str(queries))
        assert done.returncode == 1, done.stdout
        assert done.stderr.strip().splitlines() == [done.stderr.strip()], done.stderr
        assert done.stderr.strip() == ("merlion: error: the companion 1:100 refused the queries: "
                                       "Queries refused: topic name 'fish' is used twice")
        assert changed == [] and b"a crab" not in surface.tree.read(QUERIES_PATH)
    finally:
        surface.stop()
        link.stop()


def test_a_refusal_by_the_companion_app_is_an_error_too(companion):
    port, surface, changed = companion
    done = _upload(port, "--query", "a busy reef", "--negative", "sand")
    assert done.returncode == 1
    assert done.stderr.strip() == ("merlion: error: the companion 1:100 refused the queries: FTP refused: fail, "
                                   "and no status line said why")
    assert changed == [] and b"busy" not in surface.tree.read(QUERIES_PATH)


def test_a_signed_companion_takes_the_queries_only_when_signed(tmp_path):
    key = tmp_path / "key.txt"
    key.write_text("a passphrase shared by autopilot, companion and surface\n")
    port = free_udp_port()
    link = companion_link(port, signing_key_file=str(key), signing_timestamp_file=str(tmp_path / "companion.stamp"))
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=20000, push=False, ftp_writable=True),
                       queries=[QueryTopic("main", "fish", ("no fish",))])
    changed: list[list[QueryTopic]] = []
    surface.on_queries_changed(changed.append)
    surface.start()
    try:
        unsigned = _upload(port, "--query", "a crab", "--negative", "sand", "--timeout", "20")  # the NAK ends it
        # an unsigned FTP write is refused, and answered (a NAK, not silence: issue 24 item 4)
        assert unsigned.returncode == 1 and "refused the queries" in unsigned.stderr
        assert "file protected" in unsigned.stderr and changed == []
        signed = _upload(port, "--query", "a crab", "--negative", "sand", "--signing-key", str(key))
        assert signed.returncode == 0, signed.stderr
        assert "says: Queries set: a crab" in signed.stdout and changed[-1][0].positive == "a crab"
    finally:
        surface.stop()
        link.stop()


def test_no_companion_is_a_one_line_error():
    done = run_merlion("surface-queries", "--connect", f"udpout:127.0.0.1:{free_udp_port()}", "--query", "fish",
                       "--negative", "no fish", "--timeout", "2", timeout=60)
    assert done.returncode == 1
    assert done.stderr.strip() == "merlion: error: no answer from the companion 1:100 within 2 s"


@pytest.mark.parametrize("args, says", [
    (("{file}",), "queries.txt: topic main: needs a positive line and at least one negative line"),
    (("--query", "fish"), "--query 'fish': give at least one --negative"),
    (("--topic", "Fish=fish;no fish"), "--topic: topic name 'Fish'"),
    (("--topic", "a=fish;no", "--topic", "a=coral;sand"), "--topic: topic name 'a' is used twice"),
    (("--topic", "a=fish;no", "--query", "coral"), "give --query (one topic) or --topic (several), not both"),
    (("{file}", "--query", "coral"), "give FILE"),
    ((), "give a FILE, --query TEXT --negative TEXT, or --topic NAME=POS;NEG"),
    (("{missing}",), "missing.txt: cannot read the queries file"),
])
def test_bad_input_is_refused_before_anything_is_sent(companion, tmp_path, args, says):
    port, surface, changed = companion
    (tmp_path / "queries.txt").write_text("only a positive query\n")
    args = tuple(a.format(file=tmp_path / "queries.txt", missing=tmp_path / "missing.txt") for a in args)
    done = _upload(port, *args)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [done.stderr.strip()] and says in done.stderr, done.stderr
    assert changed == [] and surface.ftp.requests == 0


def test_topics_from_the_surface_reach_a_live_companion_and_the_surface_tool(tmp_path):
    """End to end: a real `merlion run` behind a UDP hub (the vehicle's router), a real `merlion surface`, and
    `merlion surface-queries --topic ... --topic ...`: the companion follows both topics and the surface tool's
    gallery lists them, with frames of each topic in its summary."""
    web_port = free_udp_port()
    hub = UdpHub(outputs=[("127.0.0.1", web_port)]).start()
    try:
        cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(tmp_path / "store")},
                           sampler={"k": 2}, source={"uri": FAST_SOURCE, "fps": 10, "realtime": True, "loop": True},
                           surface={"ftp_writable": True, "budget_bytes_per_s": 40000})
        companion = Companion("--config", str(cfg))
        companion.wait_for("companion running")
        with surface_with_page(tmp_path / "gallery", web_port, duration=120) as tool:
            done = run_merlion("surface-queries", "--connect", hub.url, "--timeout", "30",
                               "--topic", "fish=underwater image with fish;underwater image without fish",
                               "--topic", "coral=underwater image of a coral reef;underwater image of sand",
                               timeout=90)
            assert done.returncode == 0, done.stderr
            assert done.stdout.strip() == "merlion surface-queries: 1:100 says: Topics set: fish, coral"
            companion.wait_for("topics set: fish=")

            def both_topics() -> bool:
                s = page_state(tool.web)
                return ([t["name"] for t in s["topics"]] == ["fish", "coral"]
                        and {f["topic"] for f in s["summary"]} == {"fish", "coral"})

            wait_until(both_topics, 60, "the surface tool's summary holding frames of both topics")
            assert companion.terminate() == 0, companion.output
    finally:
        hub.stop()


@pytest.mark.slow
def test_the_live_companion_answers_what_words_resolved_to_and_refuses_an_unknown_word(tmp_path):
    """On the wire, against a real `merlion run` with the packaged encoder: "marine animal" is accepted and the
    companion's STATUSTEXT (on the surface page's status too) names the WordNet classes it was read as; a made-up
    word is refused, and the refusal names it; "a crab on the sea floor" is accepted as a crab (the sea floor, which
the encoder cannot see, left out)."""
    web_port = free_udp_port()
    hub = UdpHub(outputs=[("127.0.0.1", web_port)]).start()
    try:
        cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": hub.url}, store={"dir": str(tmp_path / "store")},
                           encoder={"name": "imagenet"}, source={"uri": FAST_SOURCE, "fps": 5, "loop": True},
                           surface={"ftp_writable": True, "budget_bytes_per_s": 40000})
        companion = Companion("--config", str(cfg))
        companion.wait_for("companion running", 120)
        with surface_with_page(tmp_path / "gallery", web_port, duration=120) as tool:
            done = run_merlion("surface-queries", "--connect", hub.url, "--timeout", "30",
                               "--query", "marine animal", "--negative", "no marine animal", timeout=90)
            assert done.returncode == 0, done.stderr
            assert done.stdout.strip() == "merlion surface-queries: 1:100 says: Queries set: marine animal"

            def said(start: str) -> list[str]:
                return [s["text"] for s in page_state(tool.web)["companion"]["statustext"] if s["text"].startswith(start)]

            wait_until(lambda: said("Query marine animal="), 30, "the companion's reading of the query on the page")
            line = said("Query marine animal=")[0]
            assert line.startswith("Query marine animal=26: great white shark,") and len(line) <= 50, line
            # the negative's line is the next STATUSTEXT, sent after the positive's: it may still be on its way
            wait_until(lambda: said("Query not marine animal=26: "), 30, "the negative query's reading on the page")

            done = run_merlion("surface-queries", "--connect", hub.url, "--timeout", "30",
                               "--query", "fish or blorptang", "--negative", "no fish", timeout=90)
            assert done.returncode == 1, done.stdout
            assert done.stderr.strip() == ("merlion: error: the companion 1:100 refused the queries: "
                                           "Queries refused: main: 'blorptang' unknown"), done.stderr
            wait_until(lambda: said("Queries refused: main: 'blorptang'"), 30, "the refusal on the page")

            # the operator's own words, a place the encoder cannot see included: the crab is looked for
            done = run_merlion("surface-queries", "--connect", hub.url, "--timeout", "30",
                               "--query", "a crab on the sea floor", "--negative", "no crab", timeout=90)
            assert done.returncode == 0, done.stderr
            wait_until(lambda: said("Query crab=4: "), 30, "the crab query's reading on the page")
            assert companion.terminate() == 0, companion.output
    finally:
        hub.stop()
