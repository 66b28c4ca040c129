"""Resolved queries kept on disk: a query asked before is answered in a later process without reading WordNet."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from companion.config import QueryConfig
from companion.errors import MerlionError
from companion.vision.encoders import query_cache
from companion.vision.encoders.query_cache import SHIPPED, QueryCache, read_file, resolve_cached, resolver_key
from companion.vision.encoders.query_words import UnknownWord, resolve_query
from tests.conftest import REPO, run_merlion, shared_file

QUERY = "crabs or lobsters"
DEFAULTS = [QueryConfig().positive, *QueryConfig().negatives]


@pytest.fixture
def no_wordnet(tmp_path) -> dict[str, str]:
    """Environment whose ``wn`` package has no WordNet files (an empty package ahead of the real one on the path;
    the real one's metadata, hence the cache key, is unchanged): any WordNet read fails, naming data.noun."""
    (tmp_path / "shadow" / "wn").mkdir(parents=True)
    (tmp_path / "shadow" / "wn" / "__init__.py").write_text("")
    path = os.pathsep.join([str(tmp_path / "shadow"), str(REPO), os.environ.get("PYTHONPATH", "")])
    return {"PYTHONPATH": path}


def _python(code: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO,
                          env={**os.environ, **env})


RESOLVE = """
import sys
from companion.vision.encoders.query_cache import resolve_cached
from companion.vision.encoders.query_words import wordnet_nouns
try:
    for text in sys.argv[2:] if len(sys.argv) > 2 else {queries!r}:
        print(resolve_cached(text, {cache!r}).explain())
finally:
    print("wordnet parsed:", wordnet_nouns.cache_info().currsize, file=sys.stderr)
"""


def test_a_query_resolved_before_needs_no_wordnet_in_a_later_process(tmp_path, no_wordnet):
    cache = tmp_path / "cache"
    resolved = resolve_cached(QUERY, cache)  # this process reads WordNet and writes the cache
    assert resolved == resolve_query(QUERY)
    later = _python(RESOLVE.format(queries=[QUERY], cache=str(cache)), no_wordnet)
    assert later.returncode == 0, later.stderr
    assert later.stdout.strip() == resolved.explain() and "wordnet parsed: 0" in later.stderr
    # the same process cannot read WordNet at all: a query not in the cache fails for want of its files
    fresh = _python(RESOLVE.format(queries=["sea turtle"], cache=str(cache)), no_wordnet)
    assert fresh.returncode != 0 and "data.noun is missing" in fresh.stderr


def test_the_default_queries_start_without_wordnet_from_the_shipped_file(tmp_path, no_wordnet):
    done = _python(RESOLVE.format(queries=DEFAULTS, cache=str(tmp_path / "empty")), no_wordnet)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "\n".join(resolve_query(q).explain() for q in DEFAULTS)
    assert "wordnet parsed: 0" in done.stderr
    assert not (tmp_path / "empty").exists()  # served by the package: nothing written


def test_the_shipped_file_equals_a_fresh_resolution_of_the_default_queries():
    key = resolver_key()
    assert key is not None
    assert json.loads(SHIPPED.read_text())["key"] == key, \
        "resolved_queries.json is out of step with the resolver: run python scripts/resolved_queries.py"
    assert read_file(SHIPPED, key) == {q: resolve_query(q) for q in DEFAULTS}


def test_a_query_naming_nothing_is_refused_without_reading_wordnet(tmp_path, no_wordnet):
    refused = _python(RESOLVE.format(queries=["an underwater image"], cache=str(tmp_path)), no_wordnet)
    assert refused.returncode != 0 and "names nothing to look for" in refused.stderr
    assert "wordnet parsed: 0" in refused.stderr


@pytest.mark.slow
def test_merlion_score_reads_the_cache_and_scores_with_an_unwritable_one(tmp_path, no_wordnet):
    """A real ``merlion score``: with a cache folder it cannot create it still explains and scores (one warning);
    with the cache filled by another process it scores the same without any WordNet file."""
    image = str(shared_file("suim/images/f_r_1965_.jpg"))
    args = ["score", "--encoder", "imagenet", "--explain", "--query", QUERY, "--negative", DEFAULTS[1], image]
    (tmp_path / "blocker").write_text("a file where the cache folder would go")
    unwritable = run_merlion(*args, env={"CACHE_DIRECTORY": str(tmp_path / "blocker" / "merlion")})
    assert unwritable.returncode == 0, unwritable.stderr
    assert unwritable.stderr.count("resolved query not cached") == 1
    resolve_cached(QUERY, tmp_path / "cache")
    cached = run_merlion(*args, env={"CACHE_DIRECTORY": str(tmp_path / "cache"), **no_wordnet})
    assert cached.returncode == 0, cached.stderr
    assert cached.stdout == unwritable.stdout and resolve_query(QUERY).explain() in cached.stderr


def _falsified(cache: QueryCache, text: str) -> None:
    """Write a cache file whose entry for ``text`` no resolver would give: only the cache can answer it."""
    real = resolve_query(text)
    fake = {"negated": real.negated, "left_out": [], "terms": [{"phrase": text, "noun": "tench", "how": "planted",
                                                                "classes": [0], "names": ["tench"], "context": False}]}
    cache.path.parent.mkdir(parents=True, exist_ok=True)
    cache.path.write_text(json.dumps({"format": query_cache.FORMAT, "key": cache.key, "queries": {text: fake}}))


def test_a_changed_resolver_key_misses(tmp_path, monkeypatch):
    cache = QueryCache(tmp_path)
    _falsified(cache, "crab")
    assert QueryCache(tmp_path).resolve("crab").terms[0].how == "planted"  # same key: the file answers
    monkeypatch.setattr(query_cache, "resolver_key", lambda: "another resolver")
    other = QueryCache(tmp_path)
    assert other.resolve("crab") == resolve_query("crab") and other.path != cache.path
    # a file at the new key's place written under the old key inside is not read either
    other.path.write_text(cache.path.read_text())
    assert QueryCache(tmp_path).resolve("crab") == resolve_query("crab")


def test_the_key_follows_the_resolver_source(tmp_path, monkeypatch):
    before = resolver_key()
    changed = tmp_path / "query_words.py"
    changed.write_bytes(Path(query_cache.query_words.__file__).read_bytes() + b"\n# a changed rule\n")
    fake = types.SimpleNamespace(__name__="companion.vision.encoders.query_words", __file__=str(changed))
    monkeypatch.setattr(query_cache, "RESOLVER_MODULES", (fake, *query_cache.RESOLVER_MODULES[1:]))
    resolver_key.cache_clear()
    try:
        assert resolver_key() not in (None, before)
    finally:
        monkeypatch.undo()
        resolver_key.cache_clear()
    assert resolver_key() == before


@pytest.mark.parametrize("content", [b"{not json", b"\xff\xfe", b'{"format": 2, "key": "KEY", "queries": '
                                     b'{"crab": {"negated": false, "terms": [{"classes": [5000]}]}}}'])
def test_a_corrupt_cache_file_is_ignored_with_one_line_and_rewritten(tmp_path, caplog, content):
    cache = QueryCache(tmp_path)
    cache.path.parent.mkdir(parents=True)
    cache.path.write_bytes(content.replace(b"KEY", (cache.key or "").encode()))
    with caplog.at_level(logging.WARNING, logger=query_cache.__name__):
        assert cache.resolve("crab") == resolve_query("crab")
        assert cache.resolve("lobster") == resolve_query("lobster")
    assert len(caplog.records) == 1 and str(cache.path) in caplog.records[0].getMessage()
    assert read_file(cache.path, cache.key or "") == {"crab": resolve_query("crab"), "lobster": resolve_query("lobster")}


def test_an_unwritable_cache_folder_still_resolves_with_one_line(tmp_path, caplog):
    (tmp_path / "blocker").write_text("")
    cache = QueryCache(tmp_path / "blocker" / "merlion")
    with caplog.at_level(logging.WARNING, logger=query_cache.__name__):
        assert [cache.resolve(q) for q in ("crab", "shark")] == [resolve_query("crab"), resolve_query("shark")]
    assert len(caplog.records) == 1 and "resolved query not cached" in caplog.records[0].getMessage()


def test_a_cache_file_is_bounded(tmp_path, monkeypatch):
    monkeypatch.setattr(query_cache, "MAX_QUERIES", 3)
    folder = tmp_path / query_cache.SUBDIR
    folder.mkdir()
    for i in range(query_cache.KEEP_FILES + 2):  # caches of older resolvers, oldest first
        old = folder / f"resolved-old{i}.json"
        old.write_text("{}")
        os.utime(old, ns=(i, i))
    cache = QueryCache(tmp_path)
    for q in ("crab", "shark", "eel", "ray"):
        cache.resolve(q)
    assert list(read_file(cache.path, cache.key or "")) == ["shark", "eel", "ray"]  # the oldest dropped
    kept = {p.name for p in folder.iterdir()}
    assert kept == {cache.path.name, *(f"resolved-old{i}.json" for i in range(3, query_cache.KEEP_FILES + 2))}


def test_a_refused_word_is_not_kept_and_still_gets_its_near_words(tmp_path):
    cache = QueryCache(tmp_path)
    for _ in range(2):
        with pytest.raises(UnknownWord, match="near words: .*jellyfish") as err:
            cache.resolve("jellyfsh")
        assert err.value.word == "jellyfsh"
    with pytest.raises(MerlionError, match="mixes wanted and negated"):
        cache.resolve("fish without divers")
    assert not cache.path.exists()
